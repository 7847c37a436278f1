"""One process a ``viscover launch`` supervises: its command, its log, its restarts."""

from __future__ import annotations

import subprocess
import threading
from dataclasses import dataclass, field
from pathlib import Path


@dataclass
class Child:
    """One supervised process: its command, log and restarts."""

    name: str
    cmd: list[str]
    log_path: Path
    proc: subprocess.Popen[str] | None = None
    restarts: int = 0
    exit_code: int | None = None
    pids: list[int] = field(default_factory=list)  #: every process started (restarts too)
    first_line: threading.Event = field(default_factory=threading.Event)
    lines: list[str] = field(default_factory=list)
