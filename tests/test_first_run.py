"""First run: where kernels are cached, the one-line compile notice, no process-wide settings."""

import ast
import os
import subprocess
import sys

import numpy as np
import pytest

SCRIPT = """
import os, numpy as np
import cloth_gym
from cloth_gym import metrics
from cloth_gym.sim import _numba
import numba
if "USER_CACHE" not in os.environ:
    assert "NUMBA_CACHE_DIR" not in os.environ, "importing cloth_gym set NUMBA_CACHE_DIR"
    assert not numba.config.CACHE_DIR, "importing cloth_gym changed numba's CACHE_DIR"
grid = np.zeros((4, 4), np.bool_)
metrics.mark_disc(0.0, 0.0, 1.0, -2.0, -2.0, 1.0, grid)
assert grid.sum() == 4, grid  # the four cells whose centres (±0.5, ±0.5) lie within 1 cm
print(_numba.cache_dir())
"""


def _run(cache_home, **extra_env):
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env.update(XDG_CACHE_HOME=str(cache_home), **extra_env)
    return subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=300)


def test_compile_notice_once_and_cache_in_the_package_directory(tmp_path):
    first = _run(tmp_path)
    assert first.returncode == 0, first.stderr
    assert "compiling simulator kernels" in first.stderr
    assert first.stderr.count("compiling simulator kernels") == 1
    cache = first.stdout.strip()
    assert cache.startswith(str(tmp_path / "cloth_gym" / "numba"))
    cached = [f for _, _, files in os.walk(cache) for f in files if f.endswith(".nbi")]
    assert any(f.startswith("metrics.") for f in cached), cached
    second = _run(tmp_path)  # the kernel comes from the cache: nothing compiles, nothing printed
    assert second.returncode == 0, second.stderr
    assert "compiling" not in second.stderr


CACHE_LOAD_SCRIPT = SCRIPT.replace("print(_numba.cache_dir())", """
from numba.core import event
fired = []
class Count(event.Listener):
    def on_start(self, ev):
        fired.append(ev.data["dispatcher"].py_func.__qualname__)
    def on_end(self, ev):
        pass
event.register("numba:compile", Count())
grid[:] = False
metrics.mark_disc(0.0, 0.0, 1.0, -2.0, -2.0, 1.0, grid)  # no new signature: nothing more to load or compile
stats = metrics.mark_disc.stats
print(sum(stats.cache_hits.values()), sum(stats.cache_misses.values()), len(fired))
""")


def test_compile_notice_only_when_a_kernel_compiles(tmp_path):
    """numba fires "numba:compile" only on a cache miss (a kernel loaded from the on-disk cache
    fires nothing), so the notice marks a real compile: printed by the run that compiles the one
    small kernel, not by the same script run again on the same fresh NUMBA_CACHE_DIR, which loads
    it. Cost: one small kernel compiled, two interpreter starts (a few seconds)."""
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env.update(NUMBA_CACHE_DIR=str(tmp_path / "numba"), USER_CACHE="1")
    runs = [subprocess.run([sys.executable, "-c", CACHE_LOAD_SCRIPT], env=env, capture_output=True, text=True,
                           timeout=300) for _ in range(2)]
    for run in runs:
        assert run.returncode == 0, run.stderr
    (hits1, misses1, _), (hits2, misses2, fired2) = (map(int, r.stdout.split()) for r in runs)
    assert runs[0].stderr.count("compiling simulator kernels") == 1 and (hits1, misses1) == (0, 1)
    assert (hits2, misses2, fired2) == (1, 0, 0)  # loaded from the cache, no compile event
    assert "compiling" not in runs[1].stderr


def test_user_numba_cache_dir_wins(tmp_path):
    mine = tmp_path / "mine"
    run = _run(tmp_path / "xdg", NUMBA_CACHE_DIR=str(mine), USER_CACHE="1")
    assert run.returncode == 0, run.stderr
    cached = [f for _, _, files in os.walk(mine) for f in files if f.endswith(".nbi")]
    assert any(f.startswith("metrics.") for f in cached), cached
    assert not (tmp_path / "xdg" / "cloth_gym").exists()


def test_kernels_still_run_when_numba_lacks_the_cache_hook(tmp_path):
    """A numba whose caching internals changed: a warning, numba's own cache, and working kernels."""
    script = ("import numba.core.caching as c\n"
              "del c._SourceFileBackedLocatorMixin\n" + SCRIPT.replace("print(_numba.cache_dir())",
                                                                     "assert not _numba.LOCATOR_INSTALLED"))
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env.update(XDG_CACHE_HOME=str(tmp_path), NUMBA_CACHE_DIR=str(tmp_path / "numba_own"), USER_CACHE="1")
    run = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert "no cache locator hook" in run.stderr and "numba's default cache" in run.stderr


WARM_SCRIPT = """
import numpy as np, gymnasium as gym
import cloth_gym
from numba.core import event
cloth_gym.warmup(verbose=False)
compiled = []
class Count(event.Listener):
    def on_start(self, ev):
        compiled.append(ev.data["dispatcher"].py_func.__qualname__)
    def on_end(self, ev):
        pass
event.register("numba:compile", Count())
for env_id in ["cloth_gym/CornerLift-v0", "cloth_gym/DrapeOntoTable-v0", "cloth_gym/RibbonDrop-v0"]:
    env = gym.make(env_id)
    env.reset(seed=1)
    env.action_space.seed(1)
    for _ in range(5):
        env.step(env.action_space.sample())
from cloth_gym.scenes import drape_test, run_until_settled, drape_metrics
scene = drape_test("thin_wool", sigma=5.0)
drape_metrics(scene, run_until_settled(scene, max_time_s=0.1).state)
print("compiled after warmup:", compiled)
assert not compiled, compiled
"""


def test_warmup_leaves_nothing_to_compile():
    """After ``cloth_gym.warmup()`` the envs and the drape test compile no kernel."""
    run = subprocess.run([sys.executable, "-c", WARM_SCRIPT], capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stdout + run.stderr


FAMILY_SCRIPT = """
from numba.core import event
from cloth_gym.sim import Rectangle, build_cloth
from cloth_gym.sim.collision import CollisionOptions
from cloth_gym.sim.implicit import ImplicitEuler
compiled = set()
class Count(event.Listener):
    def on_start(self, ev):
        compiled.add(ev.data["dispatcher"].py_func.__qualname__)
    def on_end(self, ev):
        pass
event.register("numba:compile", Count())
def step(preconditioner, newton_iters, limit=None, **collision):
    compiled.clear()
    m = build_cloth(Rectangle(8, 8), "thick_cotton", sigma=1.0, collision=CollisionOptions(**collision))
    ImplicitEuler(max_dt=1e-2, preconditioner=preconditioner, newton_iters=newton_iters, retry_diverged=False,
                  strain_limit_percent=limit).advance(m, m.state(), None, 2e-2, 1e-2)
    return sorted(compiled)
print(step("band", 1))
print(step("lines", 3, limit=1.0, self_collision=True))
"""


@pytest.mark.slow
def test_a_step_compiles_only_its_preconditioner_collision_pass_and_newton_passes(tmp_path):
    """In a fresh kernel cache, a band-factor step without self-collision, one Newton pass, no
    strain limiter, compiles the band's set-up and none of the line smoothers', the V-cycle's, the
    collision pass's, its coupling to the solve's, the further Newton passes' or the limiter's
    kernels; a lines step with self-collision, three Newton passes and the limiter then compiles
    the one-level set-up, the collision pass, the coupling, the Newton passes and the limiter, and
    still no V-cycle. Cost: two variants of the step compiled (about a CPU minute)."""
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env.update(NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    run = subprocess.run([sys.executable, "-c", FAMILY_SCRIPT], env=env, capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stderr
    band, lines = (set(ast.literal_eval(line)) for line in run.stdout.strip().splitlines()[-2:])
    assert {"run_implicit", "band_setup", "band_factor"} <= band, band
    assert not band & {"one_level_setup", "mg_setup", "mg_precondition", "line_solve", "collision_pass",
                       "self_collide", "couple_collision_response", "hold_on_obstacles", "newton_residual",
                       "limit_strain"}, band
    assert {"run_implicit", "one_level_setup", "line_solve", "collision_pass", "self_collide",
            "couple_collision_response", "hold_on_obstacles", "newton_residual", "limit_strain"} <= lines, lines
    assert not lines & {"mg_setup", "mg_precondition", "band_setup", "band_factor"}, lines


def test_copy_into_copies_to_the_bit_and_refuses_another_shape():
    """``copy_into`` (the kernels' array copy) writes every element of a 1-D or 2-D array, also
    into a strided view, and refuses a source of another shape instead of reading past it."""
    from cloth_gym.sim._numba import copy_into

    rng = np.random.default_rng(0)
    src = rng.standard_normal((5, 3))
    dst = np.zeros((8, 3))
    copy_into(dst[2:7], src)
    assert np.array_equal(dst[2:7], src) and not dst[:2].any() and not dst[7:].any()
    col = np.zeros((4, 2))
    copy_into(col[:, 1], src[:4, 0])
    assert np.array_equal(col[:, 1], src[:4, 0]) and not col[:, 0].any()
    with pytest.raises(ValueError, match="differ in shape"):
        copy_into(np.zeros((4, 3)), src)


def test_a_kernel_only_kernel_compiles_once_without_a_wrapper_and_python_calls_get_their_own_kernel(monkeypatch):
    """A ``kernel_only`` kernel gives compiled callers the kernel's own result, also with a default
    argument left out; numba compiles it once per signature, without the CPython wrapper (its
    library holds no ``cpython.`` function), without optimising or emitting a module of its own
    (only its callers' modules are optimised and reach the JIT engine); a call from Python gets an ordinary kernel of the same
    function, compiled then, with the same result, and is recorded by name."""
    from numba.core import codegen

    from cloth_gym.sim import _numba
    from cloth_gym.sim._numba import kernel_only, njit

    emitted, optimised = [], []
    emit = codegen.JITCodeLibrary._finalize_specific
    monkeypatch.setattr(codegen.JITCodeLibrary, "_finalize_specific",
                        lambda library: (emitted.append(library.name), emit(library))[1])
    optimise = codegen.CPUCodeLibrary._optimize_final_module
    monkeypatch.setattr(codegen.CPUCodeLibrary, "_optimize_final_module",
                        lambda library: (optimised.append(library.name), optimise(library))[1])

    @kernel_only
    def scaled_first(x, factor=2.0):
        return factor * x[0]

    @njit(cache=False)
    def caller(x):
        return scaled_first(x) + scaled_first(x, 10.0)

    @njit(cache=False)
    def other_caller(x):
        return scaled_first(x, 3.0)

    x = np.array([1.5, 0.0])
    assert caller(x) == 1.5 * 2.0 + 1.5 * 10.0 and other_caller(x) == 4.5
    assert len(scaled_first.signatures) == 2  # (x, omitted factor) and (x, float): one compile each
    emitted_kernels = {name.rsplit(".", 1)[-1] for name in emitted}
    assert {"caller", "other_caller"} <= emitted_kernels and "scaled_first" not in emitted_kernels
    optimised_kernels = {name.rsplit(".", 1)[-1] for name in optimised}
    assert {"caller", "other_caller"} <= optimised_kernels and "scaled_first" not in optimised_kernels
    for sig in scaled_first.signatures:
        names = [f.name for f in scaled_first.overloads[sig].library._final_module.functions]
        assert not any("cpython" in n for n in names)
    name = f"{__name__}.{scaled_first.py_func.__qualname__}"
    assert name not in _numba.CALLED_FROM_PYTHON
    assert scaled_first(x, 4.0) == 6.0 and scaled_first(x) == 3.0
    assert name in _numba.CALLED_FROM_PYTHON


def test_a_kernel_chosen_by_type_compiles_only_the_chosen_code_and_refuses_python(monkeypatch):
    """A ``chosen_by_type`` kernel runs, in compiled callers, the function its chooser returns for
    the argument types (an int and a float argument get different code), emits no machine code of
    its own, fails typing where the chooser returns None, and refuses a call from Python by name."""
    from numba import types
    from numba.core import codegen, errors

    from cloth_gym.sim._numba import chosen_by_type, njit

    emitted = []
    emit = codegen.JITCodeLibrary._finalize_specific
    monkeypatch.setattr(codegen.JITCodeLibrary, "_finalize_specific",
                        lambda library: (emitted.append(library.name), emit(library))[1])

    @chosen_by_type
    def twice_or_negated(a):
        if isinstance(a, types.Integer):
            return lambda a: 2 * a
        if isinstance(a, types.Float):
            return lambda a: -a
        return None

    @njit(cache=False)
    def chosen_caller(i, f):
        return twice_or_negated(i), twice_or_negated(f)

    @njit(cache=False)
    def unchosen_caller(b):
        return twice_or_negated(b)

    assert chosen_caller(3, 1.5) == (6, -1.5)
    assert len(twice_or_negated.signatures) == 2
    assert any(name.endswith(".chosen_caller") for name in emitted)
    assert not any("twice_or_negated" in name for name in emitted), emitted
    with pytest.raises(errors.TypingError, match="twice_or_negated: no implementation"):
        unchosen_caller(True)
    with pytest.raises(NotImplementedError, match="twice_or_negated: chosen by type in compiled code"):
        twice_or_negated(3)


def test_by_ref_hands_compiled_code_the_bundles_own_arrays_and_keeps_their_references_balanced():
    """``by_ref`` (the implicit step's bundles by reference) reads every field as the NamedTuple
    holds it (arrays, integers, floats, booleans), writes land in the caller's own arrays, and
    after many calls each array's Python reference count is where it was: the struct takes one
    reference per array and its destructor gives each back."""
    import sys
    from typing import NamedTuple

    from cloth_gym.sim._numba import by_ref, njit

    class Bundle(NamedTuple):
        a: np.ndarray
        n: int
        flag: bool
        w: float
        out: np.ndarray

    @njit(cache=False)
    def use(b):
        r = by_ref(b)
        r.out[0] += r.a.sum() + r.n + r.w
        r.out[1] = r.a.shape[0]
        return r.flag, r.n, r.w

    a, out = np.arange(3.0), np.zeros(2)
    bundle = Bundle(a, 2, True, 0.25, out)
    assert use(bundle) == (True, 2, 0.25)
    assert out.tolist() == [0.0 + 1.0 + 2.0 + 2 + 0.25, 3.0]
    counts = sys.getrefcount(a), sys.getrefcount(out)
    for _ in range(50):
        use(bundle)
    assert (sys.getrefcount(a), sys.getrefcount(out)) == counts
    assert out[0] == 51 * 5.25
    assert use(bundle._replace(flag=False, n=-7)) == (False, -7, 0.25)
