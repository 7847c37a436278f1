"""Every command survives its output's reader going away, as Unix tools do
(:mod:`agent.commands.console`): ``viscover launch ... | head -3`` flies the mission to its end
and records everything in its run folder; ``... | tee log`` and Ctrl-C (SIGINT to the
pipeline's process group, so ``tee`` dies first) lands every drone, records it, and exits 130;
a command whose output is its product ends quietly with 141; never a traceback. Real
processes, pipes closed early; the smallest scenario."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from agent.commands.console import EXIT_BROKEN_PIPE, PipeSafe
from tests.conftest import ROOT, repo_env, scenario_path

SMALL = str(scenario_path("two_agents_5_2"))


def _viscover(*args: str) -> list[str]:
    return [sys.executable, "-m", "agent.cli", *args]


def _run_dir(runs: Path) -> Path:
    (run,) = runs.iterdir()
    return run


def _events(run: Path) -> list[dict[str, Any]]:
    return [json.loads(x) for x in (run / "events.jsonl").read_text().splitlines()]


def _results(run: Path, aid: str) -> list[dict[str, Any]]:
    """The JSON result lines agent ``aid`` printed (its log, copied by the launcher)."""
    log = (run / "logs" / f"{aid}.log").read_text()
    return [json.loads(x) for x in log.splitlines() if x.startswith("{")]


# -- the streams themselves (in process) -----------------------------------------------------


def _broken_pipe() -> Any:
    """A text stream on a pipe whose reader is gone."""
    r, w = os.pipe()
    os.close(r)
    return os.fdopen(w, "w", encoding="utf-8")


def test_a_keep_stream_drops_output_once_its_reader_is_gone() -> None:
    raw = _broken_pipe()
    s = PipeSafe(raw, "keep")
    print("a line", file=s, flush=True)
    assert s.gone
    print("another", file=s, flush=True)
    raw.write("x" * 100)
    raw.flush()  # the descriptor now writes to /dev/null: no error at exit either
    raw.close()


def test_an_end_stream_raises_in_the_main_thread_only() -> None:
    raw = _broken_pipe()
    s = PipeSafe(raw, "end")
    raised: list[BaseException] = []

    def other() -> None:
        try:
            print("from a thread", file=s, flush=True)
        except BaseException as e:  # what the thread would die of
            raised.append(e)

    t = threading.Thread(target=other)
    t.start()
    t.join()
    assert raised == [] and s.gone
    raw.close()
    raw = _broken_pipe()
    s = PipeSafe(raw, "end")
    with pytest.raises(BrokenPipeError) as e:
        print("from main", file=s, flush=True)
    assert e.value.errno == errno.EPIPE and s.gone
    print("and then", file=s, flush=True)  # raised once
    raw.close()


# -- commands whose output is their product: a quiet 141 -----------------------------------


@pytest.mark.parametrize("args", [["scenario", "check", SMALL, SMALL], ["--help"]])
def test_output_into_a_closed_pipe_ends_quietly(args: list[str]) -> None:
    proc = subprocess.Popen(_viscover(*args), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=repo_env(), cwd=ROOT)
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()  # the reader goes away before the first line (| head -0)
    with proc.stderr:
        err = proc.stderr.read()
    assert (proc.wait(timeout=60), err) == (EXIT_BROKEN_PIPE, "")


# -- viscover launch -------------------------------------------------------------------------


def test_launch_into_head_flies_on_and_records_everything(tmp_path: Path) -> None:
    """``viscover launch S.toml | head -3``: three lines shown, then the mission completes
    unseen (exit 0), every line kept in logs/launch.log and the loss of the output said once
    there and in the events; ``viscover report`` takes the run folder with its stdout closed
    too (it writes files: it carries on)."""
    runs = tmp_path / "runs"
    launch = subprocess.Popen(_viscover("launch", SMALL, "--runs", str(runs), "--timeout", "60"),
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              env=repo_env(), cwd=tmp_path)
    assert launch.stdout is not None
    head = subprocess.Popen(["head", "-3"], stdin=launch.stdout, stdout=subprocess.PIPE,
                            text=True)
    launch.stdout.close()  # head holds the only reader
    shown, _ = head.communicate(timeout=60)
    _out, err = launch.communicate(timeout=90)
    assert len(shown.splitlines()) == 3 and shown.startswith("launch: run folder ")
    assert launch.returncode == 0, err
    assert "Traceback" not in err
    run = _run_dir(runs)
    doc = json.loads((run / "launch.json").read_text())
    assert (doc["exit_status"], doc["ended"]) == (0, "complete")
    assert {n: c["exit_code"] for n, c in doc["processes"].items()} == {"A": 0, "B": 0}
    said = (run / "logs" / "launch.log").read_text().splitlines()
    assert said[:3] == shown.splitlines()
    assert said[-1] == f"launch: complete; logs and journals in {run}"
    lost = (f"launch: the output's reader went away (Broken pipe); the mission goes on, every "
            f"line in {run / 'logs'}")
    assert lost in said
    assert [e["text"] for e in _events(run) if e["kind"] == "log" and e["source"] == "launch"] \
        == [lost]
    for aid in "AB":
        assert [r["complete"] for r in _results(run, aid)] == [True]
    report = subprocess.Popen(_viscover("report", str(run), "--no-plots"),
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              env=repo_env(), cwd=tmp_path)
    assert report.stdout is not None
    report.stdout.close()
    _out, err = report.communicate(timeout=120)
    assert (report.returncode, err) == (0, "")
    assert json.loads((run / "report" / "result.json").read_text())["complete"] is True


def _terminal_sigint() -> None:
    """In the child before exec: SIGINT's default action, as in a terminal's pipeline (a
    test run in the background of a non-interactive shell inherits SIGINT ignored, and an
    ignored signal stays ignored across exec: tee would then outlive Ctrl-C)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_ctrl_c_on_launch_into_tee_lands_everything_and_exits_130(tmp_path: Path) -> None:
    """``viscover launch S.toml | tee log``, then Ctrl-C: the terminal's SIGINT reaches the
    whole pipeline (one process group), tee ends at once, and the launcher, its output gone,
    still stops every agent in order (each exits 0, a kinematic agent's landing), records
    their exits and its own end after tee was gone, and exits 130; launch.json says why."""
    runs, tee_log = tmp_path / "runs", tmp_path / "tee.log"
    launch = subprocess.Popen(
        _viscover("launch", SMALL, "--runs", str(runs), "--timeout", "180", "--rate-scale", "1"),
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=repo_env(),
        cwd=tmp_path, process_group=0,  # a group of its own: the pipeline's, as a shell's
        preexec_fn=_terminal_sigint)
    assert launch.stdout is not None
    tee = subprocess.Popen(["tee", str(tee_log)], stdin=launch.stdout,
                           stdout=subprocess.DEVNULL, process_group=launch.pid,
                           preexec_fn=_terminal_sigint)
    launch.stdout.close()
    try:
        deadline = time.monotonic() + 60.0
        flying = False
        while time.monotonic() < deadline and launch.poll() is None and not flying:
            flying = any(line.startswith("launch: A ") and " link ok " in line for line in
                         (tee_log.read_text().splitlines() if tee_log.exists() else []))
            time.sleep(0.1)  # until the agents are flying (A's state heard)
        seen = tee_log.read_text() if tee_log.exists() else ""
        assert flying, f"launch {launch.poll()}: no 'A ... link ok' line in\n{seen[-2000:]}"
        os.killpg(launch.pid, signal.SIGINT)  # Ctrl-C
        _out, err = launch.communicate(timeout=90)
    finally:
        if launch.poll() is None:
            os.killpg(launch.pid, signal.SIGKILL)
            launch.wait()
    assert tee.wait(timeout=10) == -signal.SIGINT
    assert launch.returncode == 130, err
    assert "Traceback" not in err
    run = _run_dir(runs)
    doc = json.loads((run / "launch.json").read_text())
    assert (doc["exit_status"], doc["ended"]) == (130, "interrupted by SIGINT")
    assert {n: c["exit_code"] for n, c in doc["processes"].items()} == {"A": 0, "B": 0}
    said = (run / "logs" / "launch.log").read_text().splitlines()
    assert "launch: SIGINT: landing and stopping everything" in said
    # the last line, and the console's loss said where it was seen (before, or at that line)
    assert f"launch: interrupted by SIGINT; logs and journals in {run}" in said[-2:]
    assert sum("the output's reader went away" in line for line in said) == 1
    events = _events(run)
    assert {e["source"]: e["status"] for e in events if e["kind"] == "exit"} == {"A": 0, "B": 0}
    assert events[-1]["kind"] == "recording_end"
    assert [e["status"] for e in events if e["kind"] == "launch_end"] == [130]


@pytest.mark.long  # make test has the kinematic case (the same launcher path), just above
def test_ctrl_c_on_a_flight_into_tee_records_every_landing(tmp_path: Path) -> None:
    """The flight of the issue: ``viscover launch cube_6_2.toml --flight | tee log`` and
    Ctrl-C once the drones hover. Each drone's log goes on past "landing" to "landed", each
    landing is an event, every agent exits 0, the launch 130."""
    runs, tee_log = tmp_path / "runs", tmp_path / "tee.log"
    launch = subprocess.Popen(
        _viscover("launch", str(scenario_path("cube_6_2")), "--flight", "--time-scale", "2",
                  "--runs", str(runs)),
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=repo_env(),
        cwd=tmp_path, process_group=0)
    assert launch.stdout is not None
    tee = subprocess.Popen(["tee", str(tee_log)], stdin=launch.stdout,
                           stdout=subprocess.DEVNULL, process_group=launch.pid)
    launch.stdout.close()
    try:
        deadline = time.monotonic() + 120.0
        while time.monotonic() < deadline and sum(
                "viscover-flight-agent hovering" in line for line in
                (tee_log.read_text().splitlines() if tee_log.exists() else [])) < 3:
            time.sleep(0.2)
        os.killpg(launch.pid, signal.SIGINT)
        _out, err = launch.communicate(timeout=150)
    finally:
        if launch.poll() is None:
            os.killpg(launch.pid, signal.SIGKILL)
            launch.wait()
    assert tee.wait(timeout=10) == -signal.SIGINT
    assert launch.returncode == 130, err
    run = _run_dir(runs)
    doc = json.loads((run / "launch.json").read_text())
    assert {a: doc["processes"][a]["exit_code"] for a in "ABC"} == {"A": 0, "B": 0, "C": 0}
    landed = {e["source"] for e in _events(run) if e["kind"] == "flight"
              and e["text"].endswith(": landed")}
    assert landed == {"A", "B", "C"}
    for aid in "ABC":
        log = (run / "logs" / f"{aid}.log").read_text()
        assert "landed" in log[log.rindex("landing"):], log[-2000:]
