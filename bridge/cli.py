"""`bridge`: serve one board on eclipse-zenoh until Ctrl-C or until the board fails.

    bridge --target native|native-udp|qemu|serial:URL|crazyflie:URI --name NAME --connect tcp/HOST:PORT

The board's messages are published under rig/board/NAME/... (rig/hil/zenoh.py);
the rig replays into it with `rig replay --target zenoh:NAME --zenoh-connect ...`.
"""

from __future__ import annotations

import argparse
import faulthandler
import logging
import signal
import sys

from rig.hil.links import LinkError
from rig.hil.targets import open_target
from rig.hil.zenoh import Bridge, EndpointError, check_endpoints, open_session


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="bridge", description=__doc__.split("\n\n")[0])
    parser.add_argument("--target", required=True, help="the board link, as for rig replay")
    parser.add_argument("--name", required=True, help="board name in the key expressions")
    parser.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                        help="zenoh endpoint to connect to (a router), e.g. tcp/127.0.0.1:7447; repeatable")
    parser.add_argument("--listen", action="append", default=[], metavar="ENDPOINT", help="endpoint to listen on")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    faulthandler.register(signal.SIGUSR1, all_threads=True)      # `kill -USR1 PID`: where a stuck bridge is
    try:
        check_endpoints([*args.listen, *args.connect])
        link = open_target(args.target)
    except (EndpointError, LinkError) as exc:
        print(f"bridge: {exc}", file=sys.stderr)
        return 2
    session = None
    try:
        session = open_session(None, args.listen, args.connect)
        bridge = Bridge(session, args.name, link).start()
        print(f"bridge: serving {link.name} as {args.name}", flush=True)
        try:
            bridge.wait()
        except KeyboardInterrupt:
            pass
        finally:
            bridge.stop()
        if bridge.error:
            print(f"bridge: {bridge.error}", file=sys.stderr)
            return 1
        return 0
    except LinkError as exc:
        link.close()
        print(f"bridge: {exc}", file=sys.stderr)
        return 2
    finally:
        if session is not None:
            session.close()


if __name__ == "__main__":
    sys.exit(main())
