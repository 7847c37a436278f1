"""The CLI kit every ``viscover`` subcommand uses (the ground station's too): argument types,
the shared network arguments, scenario and mission helpers, one logging setup under the
``viscover`` logger, and :func:`run_handler`, which turns a :class:`~agent.errors.UsageError`
into one line on stderr and exit status 2, and Ctrl-C into 130.

Exit statuses (:mod:`agent.errors`): 0 ok; 1 the mission went wrong (invariant violation,
flight failure); 2 a user mistake; 3 not complete in time; 130 interrupted.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import re
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO, TypeAlias

from agent.commands.console import EXIT_BROKEN_PIPE, PipeSafe
from agent.errors import EXIT_INTERRUPTED, EXIT_USAGE, UsageError
from agent.net import security
from agent.net.router import client_config
from agent.wire import keys

if TYPE_CHECKING:  # loaded by the commands that read a scenario (numpy; router needs none)
    import threading

    from agent.config.scenario import AgentSpec, Scenario
    from agent.net.transport import ZenohTransport
    from agent.wire.signed import SigningKeys

# A string: argparse's classes are not subscriptable at run time (Python 3.11).
Subparsers: TypeAlias = "argparse._SubParsersAction[argparse.ArgumentParser]"
Handler = Callable[[argparse.Namespace], int]

#: A Zenoh endpoint: protocol/address (e.g. tcp/127.0.0.1:7447, tls/host:7447).
ENDPOINT_RE = re.compile(r"^(tcp|udp|tls|quic|ws|unixsock-stream)/\S+$")
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
_LOG_FORMAT = "%(asctime)s {tag} %(name)s %(levelname)s %(message)s"


def fail(msg: str) -> int:
    """Print ``viscover: error: msg`` on stderr; returns the usage exit status (also when
    stderr's reader is gone: the status is the message then)."""
    _say(f"viscover: error: {msg}")
    return EXIT_USAGE


def _say(line: str) -> None:
    """``line`` on stderr, if anyone still reads it."""
    with contextlib.suppress(BrokenPipeError):
        print(line, file=sys.stderr)


def run_handler(handler: Handler, args: argparse.Namespace) -> int:
    """Run a subcommand: a user mistake is one line and status 2, Ctrl-C status 130, its
    output's reader gone (``| head``; :mod:`agent.commands.console`) a quiet 141."""
    try:
        return int(handler(args))
    except UsageError as e:
        return fail(str(e))
    except KeyboardInterrupt:  # Ctrl-C: 130, also when it ended a | tee first
        _say("viscover: interrupted")
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        if not console_gone():  # a socket's, not the console's: not ours to hide
            raise
        return EXIT_BROKEN_PIPE


def console_gone() -> bool:
    """Whether the reader of this command's stdout or stderr went away."""
    return any(isinstance(s, PipeSafe) and s.gone for s in (sys.stdout, sys.stderr))


class _StderrHandler(logging.StreamHandler[TextIO]):
    """A handler writing to whatever ``sys.stderr`` is when a record is emitted (not the
    stream of when it was made: a replaced or closed stderr must not break logging)."""

    def __init__(self) -> None:
        super().__init__(sys.stderr)

    @property
    def stream(self) -> Any:
        return sys.stderr

    @stream.setter
    def stream(self, _value: Any) -> None:
        pass


def setup_logging(level: str, tag: str = "") -> None:
    """Log records of the ``viscover`` logger tree at ``level`` to stderr, one format for
    every process (``tag`` names the process, e.g. the agent id)."""
    root = logging.getLogger("viscover")
    for h in list(root.handlers):
        if getattr(h, "_viscover", False):
            root.removeHandler(h)
    handler = _StderrHandler()
    handler.setFormatter(logging.Formatter(_LOG_FORMAT.format(tag=tag or "-")))
    handler._viscover = True  # type: ignore[attr-defined]
    root.addHandler(handler)
    root.setLevel(getattr(logging, level.upper(), logging.WARNING))


# -- argument types ----------------------------------------------------------------------------


def number(text: str) -> float:
    """A finite number."""
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(x):
        raise argparse.ArgumentTypeError(f"{text} is not a finite number")
    return x


def probability(text: str) -> float:
    """A probability in [0, 1]."""
    p = number(text)
    if not 0.0 <= p <= 1.0:
        raise argparse.ArgumentTypeError(f"{text} is not a probability in [0, 1]")
    return p


def non_negative(text: str) -> float:
    """A finite number ≥ 0."""
    x = number(text)
    if not x >= 0.0:
        raise argparse.ArgumentTypeError(f"{text} must be >= 0")
    return x


def positive(text: str) -> float:
    """A finite number > 0."""
    x = number(text)
    if not x > 0.0:
        raise argparse.ArgumentTypeError(f"{text} must be > 0")
    return x


def kind_probability(text: str) -> tuple[str, float]:
    """``KIND=P``, e.g. ``trade=0.5``."""
    kind, sep, p = text.partition("=")
    if not sep or not kind:
        raise argparse.ArgumentTypeError(f"{text!r}: expected KIND=P, e.g. trade=0.5")
    return kind, probability(p)


def endpoint(text: str) -> str:
    """A Zenoh endpoint ``proto/host:port``."""
    if not ENDPOINT_RE.match(text):
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a Zenoh endpoint; write it as tcp/HOST:PORT, e.g. "
            f"{DEFAULT_ENDPOINT}")
    return text


# -- shared arguments --------------------------------------------------------------------------


def add_network_arguments(p: argparse.ArgumentParser) -> None:
    """``--zenoh``, ``--connect``, ``--connect-wait``, ``--mission``, ``--tls-dir`` and
    ``--identity``."""
    p.add_argument("--zenoh", metavar="FILE", help="Zenoh client config (json5), e.g. "
                   "broker_config/agent.json5")
    p.add_argument("--connect", metavar="ENDPOINT", type=endpoint, action="append", default=[],
                   help=f"router endpoint, e.g. {DEFAULT_ENDPOINT} (repeatable; overrides "
                   "--zenoh)")
    p.add_argument("--connect-wait", type=non_negative, default=30.0, metavar="S",
                   help="keep trying to reach the router for S seconds at start (default 30)")
    p.add_argument("--mission", help="mission name (key prefix); default: scenario name")
    p.add_argument("--tls-dir", metavar="DIR", default=None,
                   help="secured profile: the team directory of deploy/make-certs.py (mutual "
                   f"TLS, access control, signed trades); default ${security.ENV_TLS_DIR}, "
                   "unset: the open lab profile")
    p.add_argument("--identity", metavar="NAME", default=None,
                   help="certificate to present from --tls-dir (default: drone-<id> for "
                   "agents, observer for observe, ground otherwise)")


def required_option(p: argparse.ArgumentParser | argparse._ArgumentGroup, *flags: str,
                    missing: str, **kwargs: Any) -> argparse.Action:
    """An option argparse requires (``--help`` shows it so: not in brackets) whose absence
    is said in ``missing``'s one line (``viscover: error: <missing>``, exit 2) rather than
    argparse's usage and generic error (:class:`agent.cli.Parser`)."""
    action = p.add_argument(*flags, required=True, **kwargs)
    action.viscover_missing = missing  # type: ignore[attr-defined]
    return action


def missing_line(action: argparse.Action) -> str | None:
    """The line :func:`required_option` gave ``action`` (None: argparse's own)."""
    said = getattr(action, "viscover_missing", None)
    return said if isinstance(said, str) else None


def add_log_level(p: argparse.ArgumentParser) -> None:
    """``--log-level``."""
    p.add_argument("--log-level", default="WARNING", metavar="LEVEL",
                   choices=("DEBUG", "INFO", "WARNING", "ERROR", "debug", "info", "warning",
                            "error"), help="what the viscover logger writes to stderr: debug, "
                   "info, warning or error (default warning)")


# -- values ------------------------------------------------------------------------------------


def scenario_arg(path: str, *, resolve: bool = True) -> Scenario:
    """The scenario at ``path``, its mesh landmarks sampled (a ScenarioError is a usage error).

    Every process samples a mesh structure the same way (seeded), so agents, ground station
    and observer agree on landmark ids without exchanging them."""
    from agent.config.parse import load_scenario
    from agent.world.structure import resolve_structure

    sc = load_scenario(path)
    return resolve_structure(sc) if resolve else sc


def output_dir(path: str | Path, option: str = "--out") -> Path:
    """The folder ``path`` for a command's output, created and checked writable, or a usage
    error naming ``option`` and why it cannot be used."""
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise UsageError(f"{option} {out}: exists and is not a directory; choose another path")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UsageError(f"{option} {out}: cannot create directory: {e.strerror or e}") from None
    probe = out / ".viscover-write-test"
    try:
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as e:
        raise UsageError(f"{option} {out}: directory is not writable: {e.strerror or e}") \
            from None
    return out


def agent_spec(scenario: Scenario, agent_id: str, scenario_path: str) -> AgentSpec:
    """The scenario's agent ``agent_id``, or a usage error listing the agents."""
    for a in scenario.agents:
        if a.id == agent_id:
            return a
    raise UsageError(f"--id {agent_id}: not an agent of {scenario_path} "
                     f"(agents: {', '.join(a.id for a in scenario.agents)})")


def mission_name(mission: str | None, scenario: Scenario) -> str:
    """``--mission``, or the scenario's name made a valid key segment."""
    name = mission or "".join(c if c.isalnum() or c in "_-" else "_"
                              for c in scenario.name)[:32]
    try:
        return keys.validate_id(name, "mission")
    except keys.KeyFormatError as e:
        raise UsageError(f"--mission: {e}") from None


def zenoh_config(args: argparse.Namespace, role: str | None = None) -> Any:
    """The Zenoh client config of ``--connect`` / ``--zenoh`` (default the local router);
    with ``--tls-dir`` (or ``$VISCOVER_TLS_DIR``) the secured profile presenting
    ``--identity``, else ``role``, else the ground station's certificate."""
    team = security.team_dir(getattr(args, "tls_dir", None))
    if team is not None:
        return _secure_config(args, team, getattr(args, "identity", None) or role or
                              security.GROUND)
    if args.connect:
        return client_config(args.connect)
    if args.zenoh:
        import zenoh

        if not Path(args.zenoh).is_file():
            raise UsageError(f"--zenoh {args.zenoh}: no such file")
        try:
            return zenoh.Config.from_file(args.zenoh)
        except Exception as e:  # zenoh reports config errors as ZError/ValueError
            raise UsageError(f"--zenoh {args.zenoh}: {e}") from None
    return client_config([DEFAULT_ENDPOINT])


def open_session(args: argparse.Namespace, node_id: str, role: str | None = None,
                 stop: threading.Event | None = None) -> ZenohTransport:
    """The session of a network command: :func:`zenoh_config` opened within
    ``--connect-wait`` seconds (saying on stderr what it waits for), else one line naming the
    endpoint and the fix (:func:`agent.net.session.open_session`)."""
    from agent.net.session import open_session as open_zenoh

    return open_zenoh(zenoh_config(args, role), None, node_id, args.connect_wait, stop)


def _secure_config(args: argparse.Namespace, team: security.TeamDir, identity: str) -> Any:
    """The secured client config of ``--connect`` / ``--zenoh`` as ``identity``."""
    if args.connect:
        return security.client_config(team, args.connect, identity)
    if args.zenoh:
        import zenoh

        if not Path(args.zenoh).is_file():
            raise UsageError(f"--zenoh {args.zenoh}: no such file")
        try:
            cfg = zenoh.Config.from_file(args.zenoh)
        except Exception as e:  # zenoh reports config errors as ZError/ValueError
            raise UsageError(f"--zenoh {args.zenoh}: {e}") from None
        return security.secure_file_config(cfg, team, identity)
    return security.client_config(team, [security.DEFAULT_TLS_ENDPOINT], identity)


def signing_keys(args: argparse.Namespace, agent_id: str) -> SigningKeys | None:
    """Drone ``agent_id``'s trade-signing keys from ``--tls-dir`` (None: open profile)."""
    team = security.team_dir(getattr(args, "tls_dir", None))
    return None if team is None else security.load_signing(team, agent_id)


def battery_capacities(text: str, ids: list[str]) -> dict[str, float]:
    """``--battery-capacity ID=MAH,...`` (``viscover groundstation``, ``viscover launch``):
    each named simulated vehicle's own pack [mAh]; a bad entry is a :class:`UsageError`
    naming it (one line)."""
    out: dict[str, float] = {}
    for item in filter(None, (x.strip() for x in text.split(","))):
        drone, sep, mah = (part.strip() for part in item.partition("="))
        try:
            value = float(mah) if sep and drone else math.nan
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) and value > 0):
            raise UsageError(f"--battery-capacity {item!r}: expected ID=MAH, a capacity > 0 "
                             "[mAh], e.g. A=1200")
        if drone not in ids:
            raise UsageError(f"--battery-capacity {item!r}: {drone} is not an agent of the "
                             f"scenario ({', '.join(ids)})")
        if drone in out:
            raise UsageError(f"--battery-capacity {item!r}: {drone} is given twice")
        out[drone] = value
    return out
