"""``twin emulate``: the emulated rig — board on a pseudo-terminal or a TCP port, EM tracker over OpenIGTLink,
automatic fixture — for work without the rig (:class:`twin.device.emulated_rig.EmulatedRig`)."""

from __future__ import annotations

import argparse
import os
import sys
import threading

from twin.cliargs import (add_param_args, add_pose_args, count, params_from_args, pose_overrides,
                          sigterm_event)
from twin.live import add_live_argument

__all__ = ["register"]


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "emulate",
        help="run the emulated rig until Ctrl-C or SIGTERM: the board (firmware core + MuJoCo twin) on a "
             "pseudo-terminal, its EM tracker over OpenIGTLink and an automatic fixture; prints the device URL",
    )
    p.add_argument("--seed", type=count, default=0, help="sensor-noise seed of the twin")
    p.add_argument("--link", metavar="PATH", default=None,
                   help="also make PATH a symbolic link to the port (stable across replugs); PATH must not exist")
    p.add_argument("--host", default="127.0.0.1",
                   help="interface the tracker, the fixture and a --tcp board listen on (default 127.0.0.1)")
    p.add_argument("--tcp", metavar="PORT", type=int, default=None,
                   help="serve the board on this TCP port (0 picks a free one) instead of a pseudo-terminal: "
                        "the URL is then socket://HOST:PORT, for a host on another machine")
    p.add_argument("--igtl-port", type=int, default=18944,
                   help="TCP port of the tracker's OpenIGTLink server (default 18944, PLUS's; 0 picks a free one; "
                        "-1 serves no tracker)")
    p.add_argument("--fixture-port", type=int, default=18945,
                   help="TCP port of the automatic fixture (default 18945; 0 picks a free one; -1 none: the host "
                        "then asks an operator, as on the rig)")
    p.add_argument("--events", metavar="FILE", default=None,
                   help="JSON-lines schedule of hidden events applied to the twin at their simulated t_s "
                        "(twin.sim.events), which the host is not told of")
    add_live_argument(p)
    add_pose_args(p)
    add_param_args(p)
    p.set_defaults(func=run_emulate)


def run_emulate(args: argparse.Namespace) -> int:
    """Start the board, print its port and device URL, run in real time until Ctrl-C or SIGTERM."""
    from twin.device.board import TICK_S
    from twin.device.emulated_rig import EmulatedRig

    if args.tcp is not None and not 0 <= args.tcp < 65536:
        print(f"twin emulate: --tcp {args.tcp}: expected 0..65535", file=sys.stderr)
        return 2
    if args.tcp is not None and args.link is not None:
        print(f"twin emulate: --link {args.link}: a board on --tcp has no device file to link to", file=sys.stderr)
        return 2
    for name in ("igtl_port", "fixture_port"):
        if not -1 <= getattr(args, name) < 65536:
            print(f"twin emulate: --{name.replace('_', '-')} {getattr(args, name)}: expected 0..65535, or -1 for none",
                  file=sys.stderr)
            return 2
    if args.link is not None and os.path.lexists(args.link):
        # Refused at once, before the board is built; the board's own link step refuses it too
        # if something appears at PATH meanwhile.
        print(f"twin emulate: --link {args.link}: already exists; not replacing it (remove it or choose "
              "another path)", file=sys.stderr)
        return 2
    from twin.resources import NativeBuildError

    with sigterm_event() as stop:
        params = params_from_args(args)
        schedule = None
        if args.events is not None:
            from twin.sim.events import load_events

            try:
                schedule = load_events(args.events, params)
            except ValueError as exc:
                print(f"twin emulate: --events {args.events}: {exc}", file=sys.stderr)
                return 2
        try:
            # A pose given here goes into the URL printed, so that the host runs in the same one.
            rig = EmulatedRig(params, seed=args.seed, link_path=args.link, host=args.host,
                              base_rotation=params.rig.base_rotation if pose_overrides(args) else None,
                              igtl_port=None if args.igtl_port < 0 else args.igtl_port,
                              fixture_port=None if args.fixture_port < 0 else args.fixture_port,
                              board_port=args.tcp)
        except (ValueError, NativeBuildError) as exc:
            # One line: a build error's compiler output is for make to show, not this command.
            print(f"twin emulate: the board cannot start: {_first_line(exc)}", file=sys.stderr)
            return 1
        if schedule is not None:
            plant = rig.board.board.plant

            def apply_events() -> None:
                schedule.apply_due(plant)

            rig.board.tick_hooks.append(apply_events)
        try:
            rig.board.plug()  # a --link that cannot be made is the command line's one-line OSError
        except OSError as exc:
            if args.tcp is None:
                raise
            print(f"twin emulate: --host {args.host} --tcp {args.tcp}: cannot listen: {exc.strerror or exc}",
                  file=sys.stderr)
            rig.close()
            return 1
        try:
            rig.start()
        except OSError as exc:
            print(f"twin emulate: --host {args.host} --igtl-port {args.igtl_port} --fixture-port {args.fixture_port}: "
                  f"cannot listen: {exc.strerror or exc}", file=sys.stderr)
            rig.close()
            return 1
        board = rig.board
        with rig:
            print(f"port: {board.port}", flush=True)
            print(f"url:  {rig.url}", flush=True)
            if rig.igtl_server is not None:
                print(f"tracker: OpenIGTLink on {rig.host}:{rig.igtl_server.port} ({', '.join(rig.probe_names)})",
                      flush=True)
            if rig.fixture is not None:
                print(f"fixture: {rig.host}:{rig.fixture.port}", flush=True)
            try:
                _serve(board, stop, params, args)
            except KeyboardInterrupt:
                pass
            print(f"stopped after {board.ticks} ticks ({board.ticks * TICK_S:.1f} s of board time), "
                  f"{board.overruns} overruns, {board.tx_dropped_bytes} bytes dropped", flush=True)
        if board.error is not None:
            print(f"twin emulate: the board stopped: {type(board.error).__name__}: {_first_line(board.error)}",
                  file=sys.stderr)
            return 1
    return 0


def _first_line(exc: BaseException) -> str:
    return (str(exc).splitlines() or [""])[0]


def _serve(board, stop: threading.Event, params, args) -> None:
    """Wait for the stop, or for the board's thread to end (:attr:`PtyBoard.error`); with
    ``--live``, show the twin behind the port meanwhile. The board's thread steps the plant while
    this one reads it: a frame may mix two steps, which a view drawn a few times a second cannot
    show."""
    from twin.live import live_view_from_args

    view = live_view_from_args(args, params, command="emulate")
    if view is None:
        while not stop.wait(0.25) and board.error is None:
            pass
        return
    from twin.device.board import TICK_S
    from twin.device.sim_twin import SimTwin
    from twin.live import show_twin

    twin = SimTwin(board.board)
    try:
        while not stop.wait(0.25) and board.error is None:
            show_twin(view, twin, label=f"board time {board.ticks * TICK_S:.1f} s")
    finally:
        view.close()
