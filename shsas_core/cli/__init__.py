"""The ``shsas`` command line. Each subcommand lives in its own module of this package.

Every module in :data:`COMMANDS` defines ``register(subparsers)`` which adds one subparser and
sets ``func=callable(args) -> int``. The commands that start the service (``serve``, ``worker``,
``keys``) live beside what they start (``service/cli.py``, ``worker/cli.py``,
``worker/cli_keys.py``) and join through the ``shsas.commands`` entry points of the installed
package (pyproject.toml), so this package never imports ``service`` or ``worker``. Errors caused by input (:class:`ShsasError`) become one
line on stderr and exit code 2; a traceback is shown only with ``--debug``.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from shsas_core import __version__
from shsas_core.common.errors import Cancelled, ShsasError

#: Subcommand modules of this package, in the order of the help text (data flow order).
CORE_COMMANDS = ["info", "convert", "edit", "simulate", "autofocus", "backproject", "fit", "reconstruct",
                 "evaluate", "demo"]
#: Where other packages register their commands (``register(subparsers)``, as above).
ENTRY_POINT_GROUP = "shsas.commands"


def plugin_commands() -> dict[str, str]:
    """Command name -> module of the installed ``shsas.commands`` entry points, in their order."""
    from importlib.metadata import entry_points

    return {ep.name: ep.value for ep in entry_points(group=ENTRY_POINT_GROUP)}


#: Every subcommand: the core ones, then the installed service and worker commands.
COMMANDS = CORE_COMMANDS + [c for c in plugin_commands() if c not in CORE_COMMANDS]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="shsas",
        description="3D reconstruction from synthetic aperture sonar: spherical-harmonic neural "
        "scattering fields (SH-SAS), the isotropic neural baseline (Reed et al., L=0) and "
        "time-domain backprojection.",
        epilog="Run `shsas COMMAND --help` for the options of each command. Docs: docs/usage.md",
    )
    parser.add_argument("--version", action="version", version=f"shsas {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in CORE_COMMANDS:
        importlib.import_module(f".{name}", __name__).register(sub)
    for name, module in plugin_commands().items():
        if name not in CORE_COMMANDS:
            importlib.import_module(module).register(sub)
    return parser




def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except ShsasError as exc:
        if args.debug:
            raise
        print(f"shsas {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except Cancelled:
        print(f"shsas {args.command}: cancelled", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # `shsas info --json FILE | head`: the reader left; not an error of ours.
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except KeyboardInterrupt:
        print(f"shsas {args.command}: interrupted", file=sys.stderr)
        return 130
    except (FileNotFoundError, IsADirectoryError, PermissionError) as exc:
        if args.debug:
            raise
        print(f"shsas {args.command}: error: {exc.strerror}: {exc.filename}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
