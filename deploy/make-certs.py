#!/usr/bin/env python3
"""Make (or complete) a viscover team directory: a CA, one TLS certificate per drone, ground
station, observer and router, one Ed25519 trade-signing key per drone, team.json and the
secured router configuration router.json5 (layout: agent/net/security.py; README: Securing the
mesh).

  deploy/make-certs.py --out certs --drones A,B,C --host ground.local --host 192.168.10.1

Run it again with more --drones to add a drone (the CA and every other key are kept), with
--remove to take one out, with --renew to reissue every certificate and signing key under the
same CA, or with a fresh --out to start a new CA. Keep ca.key offline: only the files each
machine needs are copied to it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout

from agent.net.pki import DEFAULT_HOSTS, TeamPlan, make_team
from agent.wire import keys


def drone_ids(text: str) -> list[str]:
    """Comma-separated drone ids, each a valid key segment."""
    ids = [x for x in text.split(",") if x]
    for x in ids:
        try:
            keys.validate_id(x)
        except keys.KeyFormatError as e:
            raise argparse.ArgumentTypeError(str(e)) from None
    return ids


def main(argv: list[str] | None = None) -> int:
    """Parse the options and write the team directory; print what was written."""
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True, type=Path, help="team directory (created)")
    p.add_argument("--drones", type=drone_ids, default=[], metavar="A,B,C",
                   help="drone ids (added to those already in the directory)")
    p.add_argument("--remove", type=drone_ids, default=[], metavar="D,E",
                   help="drones leaving the team (out of team.json and the router's access "
                   "control; their files deleted)")
    p.add_argument("--host", action="append", default=[], metavar="NAME_OR_IP",
                   help="a name or address clients use to reach the router (repeatable; "
                   f"default {', '.join(DEFAULT_HOSTS)})")
    p.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                   help="router listen endpoint in router.json5 (default tls/0.0.0.0:7447)")
    p.add_argument("--paths-dir", type=Path, default=None, metavar="DIR",
                   help="where the files live on the router, for router.json5 (e.g. "
                   "/etc/viscover/certs; default: --out)")
    p.add_argument("--days", type=int, default=365, help="certificate validity (days)")
    p.add_argument("--renew", action="store_true",
                   help="reissue every certificate and signing key (same CA)")
    args = p.parse_args(argv)
    plan = TeamPlan(out=args.out, drones=args.drones, hosts=args.host or DEFAULT_HOSTS,
                    days=args.days, renew=args.renew, remove=args.remove,
                    listen=args.listen or ("tls/0.0.0.0:7447",), paths_dir=args.paths_dir)
    team = make_team(plan)
    print(f"team directory {team.path}: drones {', '.join(team.drones())}")
    print(f"written: {', '.join(plan.made)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
