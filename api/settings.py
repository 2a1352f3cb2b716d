"""Settings of the HTTP service (one data directory holds the database and all netCDF files)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

TOKEN_ENV = "AIRPUFF_API_TOKEN"
DEFAULT_MAX_POINTS = 10_000
# Points waiting (pending in queued or running jobs) at most, in all and per client
# (docs/api.md, "Limits"): a new job above them is refused with 503 or 429.
DEFAULT_MAX_PENDING_POINTS = 40_000
DEFAULT_MAX_PENDING_PER_CLIENT = 20_000
# Wall-clock limit of one point's task [s] (`airpuff serve` and `airpuff sweep`): about 60 times
# the longest run of the defaults (fine resolution, 54 s on one core, docs/performance.md).
DEFAULT_TIME_LIMIT_S = 3600.0


@dataclass(frozen=True)
class Settings:
    data_dir: Path
    max_points: int = DEFAULT_MAX_POINTS
    token: str | None = None  # bearer token required on every endpoint but /health when set
    workers: int = 2  # local Dask worker processes (ignored when scheduler is given)
    scheduler: str | None = None  # address of an existing Dask scheduler
    run_jobs: bool = True  # False: API only, jobs stay queued until a runner picks them up
    poll_interval: float = 0.25  # s, runner loop period
    retries: int = 2  # Dask retries of a point whose worker died
    max_body_bytes: int = 1_000_000
    bind_address: str = "127.0.0.1"  # the address served: its Host names are accepted (api.hosts)
    allowed_hosts: tuple[str, ...] = ()  # further Host names accepted (``*``: any)
    task_time_limit: float | None = DEFAULT_TIME_LIMIT_S  # s, wall clock of one point's task
    max_pending_points: int = DEFAULT_MAX_PENDING_POINTS  # waiting points of all clients
    max_pending_per_client: int = DEFAULT_MAX_PENDING_PER_CLIENT  # of one client address
    # True when the caller (`airpuff serve`) has already run db.init on db_path, so that the
    # app's start-up does not run the database's quick_check a second time
    database_ready: bool = False

    @classmethod
    def from_env(cls, data_dir, **kw) -> "Settings":
        token = os.environ.get(TOKEN_ENV) or None
        return cls(data_dir=Path(data_dir), token=token, **kw)

    @property
    def db_path(self) -> Path:
        return self.data_dir / "airpuff.db"

    @property
    def points_dir(self) -> Path:
        """Shared by all jobs: identical points (same key) are computed once."""
        return self.data_dir / "points"

    @property
    def jobs_dir(self) -> Path:
        return self.data_dir / "jobs"

    def job_dataset(self, job_id: str) -> Path:
        return self.jobs_dir / job_id / "sweep.nc"

    def temporary_file_folders(self) -> list[Path]:
        """The folders that atomic writes of the service write into (``.<name>.<random>.tmp``
        files, ``airpuff_core.atomic``): the points, the damaged points set aside, each job's
        folder and its figures.  A server holding ``runner.lock`` clears them at start-up."""
        from sweep.storage import DAMAGED_SUBDIR

        folders = [self.points_dir, self.points_dir / DAMAGED_SUBDIR]
        if self.jobs_dir.is_dir():
            for job in self.jobs_dir.iterdir():
                if job.is_dir():
                    folders += [job, job / "figures"]
        return folders
