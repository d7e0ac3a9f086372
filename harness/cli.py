"""Command line: ``python -m harness <command>`` (also installed as ``harness``).

Every command turns the package's own errors (``HarnessError``) into one line on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import sys

# The command table: every module that registers subcommands (``harness.commands.command``), imported here so
# that ``--help`` lists them all. Heavy imports stay inside the commands, so the table is cheap to load.
import harness.engine.cli  # noqa: F401
import harness.evaluation.cli  # noqa: F401
import harness.evaluation.reproduce_cli  # noqa: F401
import harness.evaluation.run_video  # noqa: F401
import harness.footage.cli  # noqa: F401
import harness.motion.capture_cli  # noqa: F401
import harness.motion.render_cli  # noqa: F401
import harness.posture.cli  # noqa: F401
import harness.scene.scene_cli  # noqa: F401
from harness.commands import COMMANDS, command
from harness.errors import HarnessError


def _model_info_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--model", default=None, help="model file (default: models/humanoid56.xml)")


@command("model-info", _model_info_args)
def _model_info(args: argparse.Namespace) -> int:
    """Print the body model's joints, ranges and standing height."""
    import numpy as np

    from harness.body import BodyModel, geom_z_range

    body = BodyModel.load(args.model)
    z = geom_z_range(body, body.zero_qpos())
    print(f"{body.path}: nq={body.model.nq} nv={body.model.nv} bodies={body.model.nbody - 1} "
          f"hinges={len(body.joint_names)} height={z[:, 1].max():.3f} m")
    for name, lo, hi in zip(body.joint_names, np.rad2deg(body.lower), np.rad2deg(body.upper)):
        print(f"  {name:14s} [{lo:7.1f}, {hi:6.1f}] deg")
    return 0


class _Parser(argparse.ArgumentParser):
    """argparse's parser with its errors as one line (``error: harness track: argument --seed: ...``) and exit
    status 2, like the package's own errors; ``--help`` is unchanged."""

    def error(self, message: str):
        text = " ".join(message.split())
        self.exit(2, f"error: {self.prog}: {text if len(text) <= 300 else text[:297] + '...'}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="harness", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    for name, (add_arguments, run) in sorted(COMMANDS.items()):
        p = sub.add_parser(name, help=(run.__doc__ or "").strip().splitlines()[0] if run.__doc__ else None)
        add_arguments(p)
        p.set_defaults(_run=run)
    return parser


def main(argv: list[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:              # --help (0) or a malformed command line (2, one line printed)
        return int(exc.code or 0)
    try:
        return int(args._run(args) or 0)
    except HarnessError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # output piped into head and closed early
        return 0
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
