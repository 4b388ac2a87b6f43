"""The ``cloth-gym`` command.

    cloth-gym drape --material thin_wool   the drape test: drape coefficient, node count, pictures
    cloth-gym figures [--material F.yaml]  the paper's figures (3, 8, 10, 11, 13), for its fabrics or yours
    cloth-gym fit-kes F.yaml               fit raw KES curves: fitted material, plot, R² per curve
    cloth-gym import-material F.json       convert an ARCSim (Wang 2011) material file into a material
    cloth-gym envs                         the registered env ids with their spaces and episode limits
    cloth-gym configs [--list]             where the shipped configs (materials/, train/, sweep/) are
    cloth-gym warmup                       compile every simulator kernel now (once per install)

``cloth-gym <command> --help`` gives each command's options. The simulation
commands live in cloth_gym.reports; scripts/ has the same entry points.
"""

from __future__ import annotations

import argparse
import sys

from .reports.options import REPORTS

__all__ = ["main"]


def _configs(args) -> int:
    from .materials import configs_dir

    root = configs_dir()
    if args.list:
        for path in sorted(root.glob("*/*.yaml")):
            print(path)
    else:
        print(root)
    return 0


def _envs(args) -> int:
    import gymnasium as gym

    from .envs import ENV_SPECS

    for env_id, (_entry, steps, _kwargs) in ENV_SPECS.items():
        env = gym.make(env_id)
        print(f"{env_id}  max_episode_steps={steps}  observation={env.observation_space}  "
              f"action={env.action_space}")
        env.close()
    return 0


def _warmup(args) -> int:
    from . import warmup

    warmup(envs=not args.no_envs)
    return 0


def _report(module: str):
    """A subcommand that runs ``cloth_gym.reports.<module>`` (imported only when it runs)."""
    def run(args) -> int:
        import importlib

        from .errors import ClothGymError
        from .reports.options import command_line

        mod = importlib.import_module(f"cloth_gym.reports.{module}")
        try:
            mod.run_args(args, command_line(f"cloth-gym {args.command}", args.argv))
        except (ClothGymError, OSError) as err:
            print(f"cloth-gym: error: {err}", file=sys.stderr)
            return 2
        return 0
    return run


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = argparse.ArgumentParser(prog="cloth-gym", description=__doc__.replace("``", ""),
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    for name, (module, add_options, help_text, text) in REPORTS.items():
        p = sub.add_parser(name, help=help_text, description=text, formatter_class=argparse.RawDescriptionHelpFormatter)
        add_options(p)
        p.set_defaults(run=_report(module))
    p = sub.add_parser("configs", help="where the shipped configs (materials, training, sweeps) are")
    p.add_argument("--list", action="store_true", help="print every shipped config file")
    p.set_defaults(run=_configs)
    p = sub.add_parser("envs", help="the registered env ids with their spaces")
    p.set_defaults(run=_envs)
    p = sub.add_parser("warmup", help="compile every simulator kernel now (about three CPU minutes, once)")
    p.add_argument("--no-envs", action="store_true", help="only the simulator, not the envs")
    p.set_defaults(run=_warmup)
    args = parser.parse_args(argv)
    args.argv = argv[1:]
    return args.run(args)


if __name__ == "__main__":
    sys.exit(main())
