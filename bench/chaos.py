"""Chaos campaign (``make chaos``; not part of ``make test``): seeded runs of a whole mission of
real agent processes on the secured profile (two linked routers, mutual TLS, signed trades)
while, all at once:

* **kills**: an agent is SIGKILLed and restarted from its journal (sometimes after
  ``lost_after``: it then learns that the team fenced it out);
* **stops**: an agent is frozen by SIGSTOP for 0.5-5 s, then SIGCONT;
* **partitions**: the link between the two routers (a TCP relay, :mod:`bench.chaos_net`) is
  cut for 0.5-5 s, one agent alone on the far side;
* **disk faults**: one agent's journal lives on a 256 KiB tmpfs (a private mount namespace)
  that fills in the middle of the mission, or a killed agent's journal gets one bit flipped
  in a complete record before its restart;
* **a hostile authenticated drone**: N5 holds its own team certificate and signing key and
  N4's stolen signing key; it publishes states naming N0 and N1 fenced with a proof it signed
  alone, offers to the others in N4's name from made-up poses (and commits any Accept), and
  sends junk to their trade queryables.

Each run ends when every agent process has ended (or after ``--run-timeout``). What counts,
from the survivors' journals (ground truth) and the observer (given the team's keys):
``lost`` landmarks in no ledger of an agent not fenced out and not reported orphaned;
``doubled`` landmarks owned by two such agents; ``violations`` the observer's;
``incomplete`` runs the observer did not see complete: one of the team left for good and was
not fenced out (with the hostile drone and two more out for good no majority of the seven
seats is left to fence and adopt: the survivors complete reporting the orphans when a
majority of the seats still agrees the mission is complete, else they wait until their
timeout, saying so), or the mission stalled. One JSON
line per run and a summary are appended to ``bench/results.jsonl``; a table is printed.

Run: ``python -m bench.chaos [--runs N] [--seed S] [--run-timeout S]`` (``CHAOS_KEEP=1``: keep
each run's folder, with every agent's log at INFO, in ``$TMPDIR/viscover-chaos-<seed>-*``).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from agent.config.parse import load_scenario
from agent.mission.observer import Observer, fence_keys
from agent.net.pki import TeamPlan, make_team
from agent.net.router import start_router_process, stop_router_process
from agent.net.security import TeamDir
from agent.net.security import client_config as secure_config
from agent.net.transport import ZenohTransport
from agent.protocol.machine import TradeMachine
from agent.storage.journal import Journal
from bench.bench_trade import swarm_scene_toml
from bench.chaos_hostile import Hostile
from bench.chaos_net import Relay

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results.jsonl"
AGENTS = ["N0", "N1", "N2", "N3", "N4", "N6"]
#: N5 is the hostile drone (it never runs as an agent): seven seats, so that the hostile
#: drone and two agents away at once still leave a majority to fence and adopt
TEAM = ["N0", "N1", "N2", "N3", "N4", "N5", "N6"]
LOST_AFTER = 20.0  #: [mission s] = 2 s at rate scale 10


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    return env


def _unshare() -> list[str] | None:
    """A prefix giving a private mount namespace, or None (no tmpfs disk faults then)."""
    exe = shutil.which("unshare")
    if exe is None:
        return None
    pre = [exe, "--mount", "--propagation", "private"] if os.geteuid() == 0 else \
        [exe, "--user", "--map-root-user", "--mount"]
    ok = subprocess.run([*pre, "sh", "-c", "mount -t tmpfs -o size=64k tmpfs /mnt"],
                        capture_output=True).returncode == 0
    return pre if ok else None


@dataclass
class Run:
    """One run's processes, faults and outcome."""

    seed: int
    tmp: Path
    team: TeamDir
    scene: Path
    endpoints: dict[str, str]
    procs: dict[str, subprocess.Popen[str]] = field(default_factory=dict)
    faults: list[str] = field(default_factory=list)
    codes: dict[str, list[int]] = field(default_factory=dict)
    tails: dict[str, str] = field(default_factory=dict)  #: last stderr line of each agent
    t0: float = field(default_factory=time.monotonic)
    lost_journal: set[str] = field(default_factory=set)  #: journals that died with a tmpfs

    def spawn(self, aid: str, prefix: list[str] | None = None, trigger: Path | None = None,
              ) -> None:
        side = self.endpoints.get(aid, self.endpoints["main"])
        cmd = [sys.executable, "-m", "agent.cli", "agent", "--id", aid, "--scenario",
               str(self.scene), "--connect", side, "--state-dir", str(self.tmp / aid),
               "--rate-scale", "10", "--request-timeout", "0.15", "--exit-on-complete",
               "--timeout", "150", "--tls-dir", str(self.team.path)]
        if os.environ.get("CHAOS_KEEP"):  # keep the logs, with the fence rounds' lines
            cmd += ["--log-level", "INFO"]
        if prefix is not None and trigger is not None:  # journal on a tmpfs filled later
            disk = self.tmp / aid
            disk.mkdir(parents=True, exist_ok=True)
            run = " ".join(f"'{x}'" for x in cmd)
            fill = f"dd if=/dev/zero of={disk}/fill bs=4k 2>/dev/null"
            script = (f"mount -t tmpfs -o size=256k tmpfs {disk} && {{ {run} & pid=$!; "
                      f"while [ ! -e {trigger} ]; do sleep 0.05; done; {fill}; wait $pid; }}")
            cmd = [*prefix, "sh", "-c", script]
            self.lost_journal.add(aid)
        self.procs[aid] = subprocess.Popen(cmd, stdout=subprocess.DEVNULL,
                                           stderr=subprocess.PIPE, text=True, env=_env())

    def reap(self, aid: str) -> None:
        p = self.procs[aid]
        if p.poll() is None:
            p.kill()
        _out, err = p.communicate()
        self.codes.setdefault(aid, []).append(p.returncode)
        if os.environ.get("CHAOS_KEEP"):
            with (self.tmp / f"{aid}.stderr").open("a") as fh:
                fh.write(err or "")
        lines = [x for x in (err or "").splitlines() if x.startswith("viscover:")]
        if lines:
            self.tails[aid] = lines[-1][:160]

    def note(self, what: str) -> None:
        """Record a fault, with its time since the run started [s]."""
        self.faults.append(f"{what} @{time.monotonic() - self.t0:.1f}s")


def _flip_last_complete_record(journal: Path, rng: random.Random) -> bool:
    """Flip one bit in a complete record (the last one) of ``journal``."""
    try:
        data = bytearray(journal.read_bytes())
    except OSError:
        return False
    pos = last = 0
    while pos + 8 <= len(data):
        length = int.from_bytes(data[pos:pos + 4], "little")
        if pos + 8 + length > len(data):
            break
        last, pos = pos, pos + 8 + length
    if last + 9 > len(data):
        return False
    data[last + 8 + rng.randrange(max(1, pos - last - 8))] ^= 1 << rng.randrange(8)
    journal.write_bytes(bytes(data))
    return True


def _faults(run: Run, rng: random.Random, relay: Relay, trigger: Path | None,
            stop: threading.Event) -> None:
    """The run's fault schedule (one thread): kills, stops, a partition, the disk."""
    plan: list[tuple[float, str]] = [(rng.uniform(0.5, 6.0), "kill") for _ in range(2)]
    plan += [(rng.uniform(0.5, 6.0), "stop"), (rng.uniform(0.5, 6.0), "partition")]
    if trigger is not None:
        plan.append((rng.uniform(0.5, 6.0), "disk_full"))
    t0 = time.monotonic()
    for at, kind in sorted(plan):
        if stop.wait(max(0.0, t0 + at - time.monotonic())):
            return
        live = [a for a in AGENTS if run.procs[a].poll() is None and a not in run.lost_journal]
        if kind == "disk_full" and trigger is not None:
            trigger.touch()
            run.note("disk_full")
        elif kind == "partition":
            hold = rng.uniform(0.5, 5.0)
            relay.cut()
            run.note(f"partition {hold:.1f}s")
            stop.wait(hold)
            relay.heal()
        elif kind == "stop" and live:
            aid, hold = rng.choice(live), rng.uniform(0.5, 5.0)
            run.procs[aid].send_signal(signal.SIGSTOP)
            run.note(f"stop {aid} {hold:.1f}s")
            stop.wait(hold)
            run.procs[aid].send_signal(signal.SIGCONT)
        elif kind == "kill" and live:
            aid = rng.choice(live)
            run.procs[aid].send_signal(signal.SIGKILL)
            run.reap(aid)
            away = rng.choice([rng.uniform(0.3, 1.5), rng.uniform(2.5, 4.0)])
            stop.wait(away)
            flipped = rng.random() < 0.3 and \
                _flip_last_complete_record(run.tmp / aid / "journal.bin", rng)
            run.note(f"kill {aid} {away:.1f}s" + (" +bitflip" if flipped else ""))
            run.spawn(aid)


def _ledger(run: Run, ob: Observer, aid: str, all_ids: list[int]) -> tuple[set[int], set[int]]:
    """(owned, held) of ``aid``: from its journal; else (its journal died with its tmpfs or
    is damaged, or it never ran as an agent: the hostile N5) its last published ledger."""
    if aid in AGENTS and aid not in run.lost_journal:
        m = TradeMachine(aid, all_ids)
        j = Journal(run.tmp / aid)
        try:
            for rec in j.replay():
                m.apply(rec)
            return set(m.owned), set(m.held)
        except Exception:  # damaged (the drone stayed out): its last published ledger
            pass
        finally:
            j.close()
    claims = ob.latest_claims.get(aid, ({}, {}))
    return set(claims[0]), set(claims[1])


def _truth(run: Run, ob: Observer, all_ids: list[int]) -> tuple[list[int], list[int]]:
    """(lost, doubled) landmark ids over the ledgers of the team's members not fenced out
    (:func:`_ledger`); landmarks reported orphaned (a fenced agent's that nobody adopted)
    are not lost."""
    rep = ob.snapshot()
    fenced = set(rep.fenced)
    owned: dict[int, int] = {}
    held: set[int] = set()
    for aid in TEAM:
        if aid in fenced:
            continue
        mine, hold = _ledger(run, ob, aid, all_ids)
        for lid in mine:
            owned[lid] = owned.get(lid, 0) + 1
        held |= hold
    orphaned = {int(x) for x in rep.orphaned}
    lost = sorted(set(all_ids) - set(owned) - held - orphaned)
    doubled = sorted(lid for lid, n in owned.items() if n > 1)
    return lost, doubled


def one_run(seed: int, run_timeout: float, unshare: list[str] | None) -> dict[str, Any]:
    """One seeded run (module docstring); its JSON line."""
    rng = random.Random(seed)
    tmp = Path(tempfile.mkdtemp(prefix=f"viscover-chaos-{seed}-"))
    team = make_team(TeamPlan(tmp / "team", TEAM))
    scene = tmp / "scene.toml"
    scene.write_text(f"lost_after = {LOST_AFTER}\n"
                     + swarm_scene_toml(len(TEAM), 36, seed).replace('name = "swarm',
                                                                     'name = "chaos', 1))
    sc = load_scenario(scene)
    r1, ep1 = start_router_process(team=team)
    relay = Relay(int(ep1.rsplit(":", 1)[1]))
    r2, ep2 = start_router_process(team=team, connect=[f"tls/localhost:{relay.port}"])
    far = rng.choice(AGENTS)
    run = Run(seed, tmp, team, scene, {"main": ep1, far: ep2})
    t0 = run.t0
    obs_tp = ZenohTransport(secure_config(team, [ep1], "observer"), None, "chaos-observer")
    ob = Observer(obs_tp, sc.name, TEAM, list(sc.landmark_ids), initial=sc.initial_sets(),
                  fence_keys=fence_keys(team.path))
    hostile = Hostile(team, ep1, sc, rng.randrange(2**31))
    stop = threading.Event()
    trigger = tmp / "fill-now" if unshare is not None else None
    disk_victim = rng.choice([a for a in AGENTS if a != far]) if trigger else None
    try:
        for aid in AGENTS:
            run.spawn(aid, unshare if aid == disk_victim else None, trigger)
        while len(ob.latest) < len(AGENTS) and time.monotonic() - t0 < 60.0:
            time.sleep(0.05)
        hostile.start()
        run.note("hostile N5")
        chaos = threading.Thread(target=_faults, args=(run, rng, relay, trigger, stop),
                                 daemon=True)
        chaos.start()
        deadline = time.monotonic() + run_timeout
        while time.monotonic() < deadline and (
                chaos.is_alive() or any(p.poll() is None for p in run.procs.values())):
            time.sleep(0.1)
        stop.set()
        chaos.join(10.0)
        hostile.stop()
        time.sleep(0.5)
        for aid in AGENTS:
            run.reap(aid)
        rep = ob.snapshot()
        lost, doubled = _truth(run, ob, list(sc.landmark_ids))
        return {"bench": "chaos_run", "seed": seed, "faults": len(run.faults),
                "fault_list": run.faults, "lost": len(lost), "lost_ids": lost,
                "doubled": len(doubled), "doubled_ids": doubled,
                "violations": len(rep.violations), "violation_list": rep.violations[:5],
                "complete": rep.complete, "fenced": sorted(rep.fenced),
                "orphaned": sorted(int(x) for x in rep.orphaned), "exit_codes": run.codes,
                "complete_at_s": None if rep.complete_at_s is None
                else round(rep.complete_at_s, 1), "said": run.tails,
                "disk_victim": disk_victim, "far_side": far,
                "last_states": {a: [st.incarnation, st.complete, st.phase]
                                for a, st in sorted(ob.latest.items())},
                "hostile": hostile.stats(), "wall_s": round(time.monotonic() - t0, 1)}
    finally:
        stop.set()
        hostile.stop()
        for p in run.procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGCONT)
                p.kill()
                p.communicate()
        ob.close()
        obs_tp.close()
        relay.close()
        stop_router_process(r2)
        stop_router_process(r1)
        if not os.environ.get("CHAOS_KEEP"):
            shutil.rmtree(tmp, ignore_errors=True)


def table(rows: list[dict[str, Any]]) -> str:
    """The campaign's table: one line per run and the totals."""
    head = f"{'run':>4} {'seed':>5} {'faults':>6} {'lost':>5} {'doubled':>7} " \
           f"{'violations':>10} {'incomplete':>10}  faults"
    lines = [head]
    for i, r in enumerate(rows, 1):
        lines.append(f"{i:>4} {r['seed']:>5} {r['faults']:>6} {r['lost']:>5} "
                     f"{r['doubled']:>7} {r['violations']:>10} {int(not r['complete']):>10}  "
                     + "; ".join(x.split(" @")[0] for x in r["fault_list"]))
    lines.append(f"{'all':>4} {'':>5} {sum(r['faults'] for r in rows):>6} "
                 f"{sum(r['lost'] for r in rows):>5} {sum(r['doubled'] for r in rows):>7} "
                 f"{sum(r['violations'] for r in rows):>10} "
                 f"{sum(not r['complete'] for r in rows):>10}  ({len(rows)} runs)")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=8)
    ap.add_argument("--seed", type=int, default=1, help="seed of the first run")
    ap.add_argument("--run-timeout", type=float, default=90.0, metavar="S")
    args = ap.parse_args(argv)
    unshare = _unshare()
    if unshare is None:
        print("chaos: no private mount namespace here: no tmpfs disk-full faults",
              file=sys.stderr)
    stamp = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    rows = []
    for k in range(args.runs):
        row = one_run(args.seed + k, args.run_timeout, unshare)
        rows.append(row)
        print(json.dumps(row), file=sys.stderr, flush=True)
        with RESULTS.open("a", encoding="utf-8") as fh:
            fh.write(json.dumps({**row, "run_at": stamp}) + "\n")
    summary = {"bench": "chaos_summary", "runs": len(rows),
               "faults": sum(r["faults"] for r in rows),
               "lost": sum(r["lost"] for r in rows), "doubled": sum(r["doubled"] for r in rows),
               "violations": sum(r["violations"] for r in rows),
               "incomplete": sum(not r["complete"] for r in rows), "run_at": stamp}
    with RESULTS.open("a", encoding="utf-8") as fh:
        fh.write(json.dumps(summary) + "\n")
    print(table(rows))
    return 0 if summary["lost"] == summary["doubled"] == summary["violations"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
