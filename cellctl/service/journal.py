"""The cycle journal: every cycle's outcome in SQLite, written durably before the PLC is told.

    journal = Journal.open(state_dir)
    row_id = journal.record(CycleRecord(...))      # committed and fsync'ed when this returns
    ...publish to the PLC...
    journal.attach_artifacts(row_id, ply_path, overlay_path)   # after publishing, see Daemon
    journal.last(20)

WAL mode with synchronous=FULL: a commit is on disk when record() returns, readers (`cellctl results`)
never block the service, and a power cut loses at most the cycle in progress, which the PLC has not been
told about either. The PLY and overlay PNG of a cycle live under state_dir/cycles/<row id>/; only the newest
`keep_artifacts` cycles keep them (the rows themselves are small and all kept).

The PLC waits for record()'s commit, so nothing else rides on it (the service's cycle journal, see Daemon):
- WAL checkpoints: SQLite's own run inside the commit that fills the WAL past 1000 pages (every ~100 cycles,
  ~8 pages a row) and fsync the database file there, +10-30 ms on this host's disk against a 2-4 ms commit.
  `WalCheckpointer` turns them off for its journal and runs them on a thread of its own while the service
  waits for a trigger, once every CHECKPOINT_COMMITS commits.
- The artifact columns' updates (attach_artifacts, prune_artifacts, on the daemon's thread between cycles)
  commit without an fsync of their own: a trigger arriving meanwhile waited for one (48 ms seen). They are
  made durable by the next cycle's commit or checkpoint; a power cut before that loses only the update, and
  prune_orphans() removes the folder it would have recorded at the next start.
"""

from __future__ import annotations

import contextlib
import json
import logging
import shutil
import sqlite3
import threading
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

#: Commits (cycle rows, artifact updates) between two WAL checkpoints of a `WalCheckpointer`. A cycle's row
#: with a 300-point glue path is ~8 WAL pages, its artifact update as many: 32 commits are ~1 MB of WAL,
#: which a checkpoint writes into the database file in ~10 ms here. Not every cycle: after a checkpoint the
#: next commit restarts the WAL and syncs its header too (a checkpoint after every cycle doubled the cycle's
#: commit, 8 ms against 4, measured); SQLite's own default waits for 1000 pages (~4 MB), as long as it likes.
CHECKPOINT_COMMITS = 32
#: SQLite's own checkpoint threshold (pages), restored when a `WalCheckpointer` stops.
SQLITE_AUTOCHECKPOINT_PAGES = 1000
JOURNAL_FILE = "journal.sqlite3"  # in the state directory

SCHEMA = """
CREATE TABLE IF NOT EXISTS cycles (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    cycle INTEGER NOT NULL,            -- the PLC's cycle number (register 2)
    triggered_at REAL NOT NULL,        -- wall clock, Unix seconds
    status TEXT NOT NULL,              -- 'ok' or 'error'
    error_code INTEGER NOT NULL,       -- firmware_io ErrorCode, 0 = none
    reason TEXT,                       -- why it failed, in words
    length_mm REAL,
    heel_height_mm REAL,
    toe_height_mm REAL,
    cycle_time_ms REAL NOT NULL,       -- trigger received -> result ready to publish
    timings TEXT NOT NULL,             -- JSON {step: seconds}
    glue_path TEXT NOT NULL,           -- JSON [[x, y, z], ...] table frame, mm
    source TEXT NOT NULL,              -- JSON: where the pair came from (backend, scene, devices)
    ply_path TEXT,
    overlay_path TEXT,
    recipe INTEGER NOT NULL DEFAULT 0,  -- recipe the PLC selected (map v2 register 7; 0 = cell default)
    in_tolerance INTEGER,              -- 1 within every checked tolerance, 0 not, NULL nothing checked
    failed_features TEXT NOT NULL DEFAULT '[]'  -- JSON ["LENGTH", ...]: features outside their tolerance
);
"""
#: Columns added after the first release, with their definition: added to older journals when opened.
ADDED_COLUMNS = {
    "recipe": "INTEGER NOT NULL DEFAULT 0",
    "in_tolerance": "INTEGER",
    "failed_features": "TEXT NOT NULL DEFAULT '[]'",
}

#: What a cycle's summary shows wherever it is listed (the journal's first columns, the CSV exports).
SUMMARY_FIELDS = (
    "id",
    "cycle",
    "triggered_at",
    "status",
    "error_code",
    "reason",
    "length_mm",
    "heel_height_mm",
    "toe_height_mm",
    "cycle_time_ms",
)

COLUMNS = (
    *SUMMARY_FIELDS,
    "timings",
    "glue_path",
    "source",
    "ply_path",
    "overlay_path",
    *ADDED_COLUMNS,
)
_JSON_COLUMNS = ("timings", "glue_path", "source", "failed_features")


@dataclass
class CycleRecord:
    """One cycle as journaled."""

    cycle: int
    triggered_at: float
    status: str
    error_code: int
    cycle_time_ms: float
    reason: str | None = None
    length_mm: float | None = None
    heel_height_mm: float | None = None
    toe_height_mm: float | None = None
    timings: dict[str, float] = field(default_factory=dict)
    glue_path: list[list[float]] = field(default_factory=list)
    source: dict[str, Any] = field(default_factory=dict)
    ply_path: str | None = None
    overlay_path: str | None = None
    id: int | None = None
    recipe: int = 0
    in_tolerance: bool | None = None  # None: no tolerance checked
    failed_features: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class Journal:
    """The SQLite journal under a state directory. One writer (the service), any number of readers."""

    def __init__(self, connection: sqlite3.Connection, state_dir: Path) -> None:
        self._db = connection
        self.state_dir = state_dir
        # A reader may open an older journal it must not change: it reads the columns that are there.
        present = {row[1] for row in connection.execute("PRAGMA table_info(cycles)")}
        self._select = ", ".join(name for name in COLUMNS if name in present)
        #: Transactions this connection has committed (a `WalCheckpointer` counts them).
        self.commits = 0

    @property
    def path(self) -> Path:
        return self.state_dir / JOURNAL_FILE

    @classmethod
    def open(cls, state_dir: str | Path, *, readonly: bool = False) -> Journal:
        state = Path(state_dir)
        path = state / JOURNAL_FILE
        if path.exists() and not path.is_file():
            raise ValueError(f"journal {path} is not a file (a directory?): move it away")
        if readonly and not path.is_file():
            raise FileNotFoundError(f"no journal at {path}: has `cellctl run` run with this state directory?")
        if not readonly:
            try:
                state.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise ValueError(f"cannot create the state directory {state}: {exc.strerror}") from None
        return cls(_connect(path, readonly), state)

    def close(self) -> None:
        self._db.close()

    def record(self, record: CycleRecord) -> int:
        """Write one cycle and commit; returns its row id."""
        values = record.to_dict()
        values.pop("id")
        for name in _JSON_COLUMNS:
            values[name] = json.dumps(values[name], allow_nan=False)
        names = ", ".join(values)
        marks = ", ".join(f":{name}" for name in values)
        with self._transaction():
            cursor = self._db.execute(f"INSERT INTO cycles ({names}) VALUES ({marks})", values)
        if cursor.lastrowid is None:  # sqlite3 sets it after every INSERT; None would be a driver fault
            raise sqlite3.DatabaseError("the journal's INSERT returned no row id")
        record.id = cursor.lastrowid
        return record.id

    def last_cycle(self) -> int:
        """The PLC cycle number journaled last (0 for an empty journal): it was answered before a restart."""
        row = self._db.execute("SELECT cycle FROM cycles ORDER BY id DESC LIMIT 1").fetchone()
        return 0 if row is None else int(row["cycle"])

    def amend_error(self, row_id: int, error_code: int, reason: str) -> None:
        """Turn a journaled cycle into an error after the fact (the link answered it with a timeout)."""
        with self._transaction():
            self._db.execute(
                "UPDATE cycles SET status = 'error', error_code = ?, reason = ?, length_mm = NULL, "
                "heel_height_mm = NULL, toe_height_mm = NULL, glue_path = '[]' WHERE id = ?",
                (error_code, reason, row_id),
            )

    def artifact_dir(self, row_id: int) -> Path:
        return self.state_dir / "cycles" / f"{row_id:08d}"

    def attach_artifacts(self, row_id: int, ply_path: Path | None, overlay_path: Path | None) -> None:
        """Record a cycle's artifact files (cellctl.service.artifacts renames their folder into place first).

        A crash between that rename and this commit leaves a folder no row refers to; prune_orphans()
        removes it (and staging leftovers) at the next start.
        """
        with self._transaction(synced=False):
            self._db.execute(
                "UPDATE cycles SET ply_path = ?, overlay_path = ? WHERE id = ?",
                (
                    None if ply_path is None else str(ply_path),
                    None if overlay_path is None else str(overlay_path),
                    row_id,
                ),
            )

    def prune_orphans(self) -> int:
        """Delete artifact folders no row refers to (a crash between writing and recording); returns how many."""
        root = self.state_dir / "cycles"
        staged = self.state_dir / "partial"  # cellctl.service.artifacts writes here before the rename
        leftovers = list(staged.iterdir()) if staged.is_dir() else []
        for folder in leftovers:
            shutil.rmtree(folder, ignore_errors=True)
        if not root.is_dir():
            return len(leftovers)
        referenced = {
            str(Path(path).parent)
            for row in self._db.execute("SELECT ply_path, overlay_path FROM cycles").fetchall()
            for path in (row["ply_path"], row["overlay_path"])
            if path is not None
        }
        orphans = [folder for folder in root.iterdir() if str(folder) not in referenced]
        for folder in orphans:
            if folder.is_dir():
                shutil.rmtree(folder, ignore_errors=True)
            else:
                folder.unlink(missing_ok=True)
        return len(orphans) + len(leftovers)

    def prune_artifacts(self, keep: int) -> int:
        """Delete the artifacts of all but the newest `keep` cycles that have any; returns how many went."""
        rows = self._db.execute(
            "SELECT id FROM cycles WHERE ply_path IS NOT NULL OR overlay_path IS NOT NULL "
            "ORDER BY id DESC LIMIT -1 OFFSET ?",
            (keep,),
        ).fetchall()
        if not rows:
            return 0
        for row in rows:
            shutil.rmtree(self.artifact_dir(row["id"]), ignore_errors=True)
        with self._transaction(synced=False):
            self._db.executemany(
                "UPDATE cycles SET ply_path = NULL, overlay_path = NULL WHERE id = ?", [(row["id"],) for row in rows]
            )
        return len(rows)

    @contextlib.contextmanager
    def _transaction(self, synced: bool = True) -> Iterator[None]:
        """One transaction, committed (and counted in `commits`) or rolled back. Not synced: committed without
        an fsync (synchronous=NORMAL under WAL), durable with the next synced commit or checkpoint, which fsync
        the whole WAL, in order; for what the PLC is not told."""
        if not synced:
            self._db.execute("PRAGMA synchronous=NORMAL")
        try:
            with self._db:
                yield
            self.commits += 1
        finally:
            if not synced:
                self._db.execute("PRAGMA synchronous=FULL")

    def set_wal_autocheckpoint(self, pages: int) -> None:
        """SQLite's own checkpoints inside the commits: every `pages` pages of WAL, or none (0: WalCheckpointer
        checkpoints between cycles instead)."""
        if pages < 0:
            raise ValueError(f"wal_autocheckpoint pages must be 0 or more, got {pages}")
        self._db.execute(f"PRAGMA wal_autocheckpoint={int(pages)}")

    def last(self, count: int | None = None) -> list[CycleRecord]:
        """The newest `count` cycles (all when None), oldest first."""
        limit = -1 if count is None else count
        rows = self._db.execute(f"SELECT {self._select} FROM cycles ORDER BY id DESC LIMIT ?", (limit,)).fetchall()
        return [_record(row) for row in reversed(rows)]

    def get(self, row_id: int) -> CycleRecord | None:
        """The journaled cycle with this row id."""
        row = self._db.execute(f"SELECT {', '.join(COLUMNS)} FROM cycles WHERE id = ?", (row_id,)).fetchone()
        return None if row is None else _record(row)

    def find(self, cycle: int) -> CycleRecord | None:
        """The newest journaled cycle with this PLC cycle number."""
        row = self._db.execute(
            f"SELECT {self._select} FROM cycles WHERE cycle = ? ORDER BY id DESC LIMIT 1", (cycle,)
        ).fetchone()
        return None if row is None else _record(row)


class WalCheckpointer:
    """Checkpoints a journal's WAL on a thread of its own, started while the service waits for a trigger.

        checkpoints = WalCheckpointer(journal)   # SQLite's checkpoints in the journal's commits stop
        checkpoints.idle()                       # between cycles: one checkpoint if CHECKPOINT_COMMITS are due
        checkpoints.close()                      # before journal.close(); SQLite's own come back

    PASSIVE checkpoints, on a connection of the thread's own: they never wait for, nor lock out, the journal's
    writer or readers, and copy what no reader still needs (a `cellctl results` reading meanwhile only leaves
    more for the next one). A checkpoint is file work with the GIL released (sqlite3), so one still running
    when the next trigger comes takes no core from the cycle, and it ends long before that cycle's commit.
    Construct and call idle() and close() on the journal's thread.
    """

    def __init__(self, journal: Journal, every: int = CHECKPOINT_COMMITS) -> None:
        self._journal = journal
        self._every = every
        self._requested_at = journal.commits  # the journal's commit count at the last checkpoint requested
        self._due = threading.Condition()
        self._pending = False
        self._closing = False
        self.done = 0  # checkpoints run
        journal.set_wal_autocheckpoint(0)
        self._thread = threading.Thread(target=self._run, args=(journal.path,), name="journal checkpoints", daemon=True)
        self._thread.start()

    def idle(self) -> None:
        """The service waits for a trigger (the PLC has its answer): a checkpoint if enough has been committed."""
        if self._journal.commits - self._requested_at < self._every:
            return
        self._requested_at = self._journal.commits
        with self._due:
            self._pending = True
            self._due.notify_all()

    def wait_done(self, count: int, timeout_s: float) -> bool:
        """True once `count` checkpoints have run (for tests)."""
        with self._due:
            return self._due.wait_for(lambda: self.done >= count, timeout_s)

    def close(self) -> None:
        with self._due:
            self._closing = True
            self._due.notify_all()
        self._thread.join(10.0)
        self._journal.set_wal_autocheckpoint(SQLITE_AUTOCHECKPOINT_PAGES)

    def _run(self, path: Path) -> None:
        try:
            db = sqlite3.connect(path)
            db.execute("PRAGMA synchronous=FULL")  # the WAL synced before it is copied, the database file after
        except sqlite3.Error as exc:
            log.warning("journal checkpoints not possible (%s): the WAL grows until the service stops", exc)
            return
        try:
            while True:
                with self._due:
                    self._due.wait_for(lambda: self._pending or self._closing)
                    if self._closing:
                        return
                    self._pending = False
                try:
                    db.execute("PRAGMA wal_checkpoint(PASSIVE)").fetchone()
                except sqlite3.Error as exc:  # the next request tries again; the journal's commits go on
                    log.warning("journal checkpoint failed: %s", exc)
                with self._due:
                    self.done += 1
                    self._due.notify_all()
        finally:
            db.close()


def _connect(path: Path, readonly: bool) -> sqlite3.Connection:
    """The journal's database: read-only, or for the writer in WAL mode, durable at commit, schema up to date."""
    try:
        db = sqlite3.connect(f"file:{path}?mode=ro", uri=True) if readonly else sqlite3.connect(path)
        if readonly:
            db.execute("SELECT 1 FROM cycles LIMIT 1")
        else:
            db.execute("PRAGMA journal_mode=WAL")
            db.execute("PRAGMA synchronous=FULL")  # durable at commit, the promise made to the PLC
            db.executescript(SCHEMA)
            _add_columns(db)
    except sqlite3.Error as exc:
        raise ValueError(
            f"journal {path} cannot be used ({exc}): is it a cellctl journal? move it away to start a new one"
        ) from None
    db.row_factory = sqlite3.Row
    return db


def _add_columns(db: sqlite3.Connection) -> None:
    """Bring a journal written by an older release up to this schema (its rows get the defaults)."""
    present = {row[1] for row in db.execute("PRAGMA table_info(cycles)")}
    with db:
        for name, definition in ADDED_COLUMNS.items():
            if name not in present:
                db.execute(f"ALTER TABLE cycles ADD COLUMN {name} {definition}")


def _record(row: sqlite3.Row) -> CycleRecord:
    values = dict(row)
    for name in _JSON_COLUMNS:
        if name in values:
            values[name] = json.loads(values[name])
    if values.get("in_tolerance") is not None:
        values["in_tolerance"] = bool(values["in_tolerance"])
    return CycleRecord(**values)
