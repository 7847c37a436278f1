"""What :mod:`viscover.api` reads and runs without a mesh: a run folder (:class:`Run`) and a
mission simulated in memory (:func:`simulate`, ``viscover simulate``)."""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from agent.errors import UsageError

if TYPE_CHECKING:
    from agent.config.scenario import Scenario
    from agent.sim.result import SimResult
    from agent.testing.rehearsal import Outcome

__all__ = ["Run", "Simulation", "scenario_of", "simulate"]


def scenario_of(path: str | os.PathLike[str]) -> Scenario:
    """The scenario file at ``path``, checked (a :class:`UsageError` naming what is wrong)."""
    from agent.commands import kit

    return kit.scenario_arg(str(path))


@dataclass(frozen=True)
class Run:
    """A run folder (``viscover launch``'s, or ``viscover simulate --out``'s)."""

    path: Path

    def _json(self, name: str) -> dict[str, Any] | None:
        try:
            doc = json.loads((self.path / name).read_text(encoding="utf-8"))
        except FileNotFoundError:
            return None
        except (OSError, ValueError) as e:
            raise UsageError(f"{self.path / name}: cannot read it as JSON: {e}") from None
        return doc if isinstance(doc, dict) else None

    def launch(self) -> dict[str, Any] | None:
        """``launch.json``: scenario, router, commands, processes, exit status, how it ended."""
        return self._json("launch.json")

    def observer(self) -> dict[str, Any] | None:
        """``observer.json``: the observer's report (violations, completion, owners, lost)."""
        return self._json("observer.json")

    def rehearsal(self) -> dict[str, Any] | None:
        """``rehearsal.json`` of a simulation under faults: faults, lost drones, violations,
        the observer's report."""
        return self._json("rehearsal.json")

    def result(self) -> dict[str, Any]:
        """``result.json`` (here or in ``report/``), built from the recording as ``viscover
        report --no-plots`` builds it when there is none yet (needs the ``ground`` extra)."""
        from agent.commands.export_plan import find_result, read_result

        with contextlib.suppress(UsageError):
            return read_result(find_result(self.path))
        from agent.commands.report import write_result_json

        return read_result(write_result_json(self.path, self.path / "report"))


@dataclass
class Simulation:
    """A mission simulated in memory (:func:`simulate`): its ``result`` (what ``result.json``
    holds), with faults the ``outcome`` an observer saw (invariants, lost drones), the
    ``status`` ``viscover simulate`` would exit with, and the folder written (``out``)."""

    result: SimResult
    outcome: Outcome | None
    status: int
    out: Path | None

    @property
    def complete(self) -> bool:
        """The mission completed (an inspection: every capturable landmark captured)."""
        return bool(self.result.complete)


def simulate(scenario: str | os.PathLike[str], out: str | os.PathLike[str] | None = None, *,
             seed: int | None = None, drop: float = 0.0, dup: float = 0.0,
             jitter: float = 0.0, lose: Sequence[str] = (), fault_seed: int = 0,
             engine: str = "agents", plots: bool = False) -> Simulation:
    """``viscover simulate``: the mission of ``scenario`` in memory on virtual time with the
    agents' own code (``engine="lockstep"``: the lockstep engines), optionally under faults
    (``drop`` and ``dup`` probabilities, ``jitter`` [s], ``lose`` ``"ID@T"`` drones lost at
    mission time T [s], seeded by ``fault_seed``; watched by an observer); with ``out`` the
    report is written there (``result.json``, ``rehearsal.json``; ``plots``: the plots and
    report.html too, needs the ``ground`` extra)."""
    from agent.commands.simulate import check_engine, exit_status, run_simulation
    from agent.sim.report import write_report
    from agent.testing.rehearsal import faults_of

    sc = scenario_of(scenario)
    if seed is not None:
        if seed < 0:
            raise UsageError(f"seed {seed}: must be a non-negative integer")
        sc = sc.with_seed(seed)
    faults = faults_of(drop=drop, dup=dup, jitter=jitter, lose=lose, seed=fault_seed)
    rehearsing = faults.any or fault_seed != 0
    check_engine(sc, engine, "engine", faulted=rehearsing)
    result, outcome = run_simulation(sc, engine, faults if rehearsing else None)
    status = exit_status(result, outcome)
    folder = None
    if out is not None:
        from agent.commands import kit
        from agent.commands.simulate import write_rehearsal

        folder = kit.output_dir(Path(out))
        write_report(result, folder, plots=plots)
        if outcome is not None:
            write_rehearsal(folder, faults, outcome)
    return Simulation(result, outcome, status, folder)
