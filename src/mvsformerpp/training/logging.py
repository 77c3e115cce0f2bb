"""Run logs: ``metrics.jsonl`` (one JSON object per row) and TensorBoard events in ``tb/``."""

from __future__ import annotations

import json
import math
from pathlib import Path

from mvsformerpp.errors import MissingDependencyError
from mvsformerpp.utils.atomic import atomic_write_text


def _clean(v):
    return None if isinstance(v, float) and not math.isfinite(v) else v


class MetricsLog:
    """Appends rows to ``metrics.jsonl``; TensorBoard scalars too when ``tensorboard``."""

    def __init__(self, run_dir: Path, tensorboard: bool, resume_step: int | None = None):
        self.path = Path(run_dir) / "metrics.jsonl"
        if resume_step is not None:
            self.truncate(resume_step)
        elif self.path.exists():
            self.path.unlink()
        self.writer = None
        if tensorboard:
            try:
                from torch.utils.tensorboard import SummaryWriter
            except ImportError as e:
                raise MissingDependencyError("tensorboard", "train", "TensorBoard logging (tensorboard: true)") from e
            self.writer = SummaryWriter(str(Path(run_dir) / "tb"), purge_step=resume_step)

    def truncate(self, step: int) -> None:
        """Drop rows written after ``step`` (a resumed run writes them again)."""
        if not self.path.exists():
            return
        keep = [line for line in self.path.read_text().splitlines() if line.strip()
                and json.loads(line).get("step", 0) <= step]
        atomic_write_text(self.path, "".join(line + "\n" for line in keep))

    def write(self, row: dict, prefix: str = "train") -> None:
        row = {k: _clean(v) for k, v in row.items()}
        with open(self.path, "a") as f:
            f.write(json.dumps(row) + "\n")
        if self.writer is not None:
            for k, v in row.items():
                if k not in ("step", "epoch", "split") and isinstance(v, (int, float)) and v is not None:
                    self.writer.add_scalar(f"{prefix}/{k}", v, row["step"])

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()


def read_metrics(run_dir: str | Path) -> list[dict]:
    """The rows of ``RUN_DIR/metrics.jsonl``."""
    path = Path(run_dir) / "metrics.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()] if path.exists() else []
