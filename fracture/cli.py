"""``fracref``: the command line.

``fracref run CONFIG [--out DIR] [--set key.path=value ...] [--until STAGE] [--force]``
``fracref config CONFIG [--set ...]`` prints the resolved config.
``fracref stages`` lists the stages.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from fracture.errors import ConfigError


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="fracref", description="Physics-inspired adaptive fracture refinement.")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    r = sub.add_parser("run", help="run an experiment config into a run directory")
    r.add_argument("config", type=Path, help="experiment YAML file")
    r.add_argument("--out", type=Path, help="run directory (default: runs/<name>)")
    r.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY.PATH=VALUE",
                   help="override a config value (YAML syntax); repeatable")
    r.add_argument("--until", metavar="STAGE", help="last stage to run")
    r.add_argument("--force", action="store_true", help="replace an existing run directory")
    r.add_argument("--quiet", action="store_true", help="no progress bars")

    c = sub.add_parser("config", help="print the resolved config")
    c.add_argument("config", type=Path)
    c.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY.PATH=VALUE")

    sub.add_parser("stages", help="list the pipeline stages")
    return p


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    from fracture import runner
    from fracture.atomic import RunDirectoryExists
    from fracture.config import dump_config, load_config
    from fracture.errors import InputError, StageError

    try:
        if args.command == "stages":
            print("\n".join(runner.available_stages()))
            return 0
        cfg = load_config(args.config, args.overrides)
        if args.command == "config":
            sys.stdout.write(dump_config(cfg))
            return 0
        runner.stages_until(args.until)  # reject a bad --until before any work
        out = args.out if args.out is not None else Path("runs") / cfg["name"]
        done = runner.run(cfg, out, until=args.until, force=args.force, progress=not args.quiet)
        print(f"run complete: {done}  (manifest: {done / 'manifest.json'})")
        return 0
    except (ConfigError, InputError, StageError, RunDirectoryExists) as exc:
        print(f"fracref: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("fracref: interrupted; nothing was written", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
