"""The ``cloth-gym`` command.

    cloth-gym configs             the directory of the shipped configs (materials/, train/)
    cloth-gym configs --list      every shipped config file, one path a line
    cloth-gym envs                the registered env ids with their spaces and episode limits
"""

from __future__ import annotations

import argparse
import sys

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

    for env_id, (_entry, steps) in ENV_SPECS.items():
        env = gym.make(env_id)
        print(f"{env_id}  max_episode_steps={steps}  observation={env.observation_space}  "
              f"action={env.action_space}")
        env.close()
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="cloth-gym", description="cloth_gym from the terminal")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("configs", help="where the shipped configs (materials, training) are")
    p.add_argument("--list", action="store_true", help="print every shipped config file")
    p.set_defaults(run=_configs)
    p = sub.add_parser("envs", help="the registered env ids with their spaces")
    p.set_defaults(run=_envs)
    args = parser.parse_args(argv)
    return args.run(args)


if __name__ == "__main__":
    sys.exit(main())
