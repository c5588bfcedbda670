"""``divas session export-points SESSION --out P.json [--object N]``: a saved session's
clicks as 3D points.

Writes a prompts file (``docs/prompts-file.md``) whose ``points`` are the clicks of one
object (default: the last one holding clicks): each click's back-projected 3D point, in
the scene's frame, with its label. ``divas segment`` (or ``divas batch``) on the same
scene, or on another capture of the same set in the same frame, then picks anchors that
see these points and runs the loop from them.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..output_paths import check_outputs


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("session", help="work with saved sessions (export-points)")
    cmds = p.add_subparsers(dest="session_command", required=True, metavar="SUBCOMMAND")
    e = cmds.add_parser(
        "export-points",
        help="write a session's clicks as the 3D points of a prompts file",
        description="Write a prompts file (docs/prompts-file.md) whose 'points' are the "
        "clicks of one object of a saved session: each click's back-projected 3D point, in "
        "the scene's frame, with its label.",
    )
    e.add_argument("session", type=Path, help="a saved session (its .json)")
    e.add_argument("--out", type=Path, required=True, help="the prompts file to write")
    e.add_argument(
        "--object",
        type=int,
        default=None,
        metavar="N",
        help="the object's index (default: the last one holding clicks)",
    )
    e.set_defaults(func=run_export_points)


def run_export_points(args: argparse.Namespace) -> int:
    from ..session.point_prompts import session_points
    from ..session.store import load_state
    from ..session.validate import check_session_doc

    check_outputs([("--out", args.out)], [args.session])
    doc, arrays = load_state(args.session)
    check_session_doc(args.session, doc, arrays)
    prompts = session_points(doc, args.object, args.session)
    prompts.write(args.out)
    pos = sum(p.positive for p in prompts.points)
    print(
        f"{len(prompts.points)} points ({pos} positive, {len(prompts.points) - pos} negative) "
        f"→ {args.out}"
    )
    return 0


__all__ = ["add_parser", "run_export_points"]
