"""A campaign's results folder: nothing finished is lost, and one folder holds one campaign.

Layout of ``DIR``:

- ``campaign.yaml``: the campaign file's text, and ``campaign.json``: its name, where it was
  read, the folder its relative paths are resolved in and its SHA-256 (a rerun with another
  file is refused);
- ``records.jsonl``: one JSON line appended (and flushed to disk) per scenario as it ends, or
  per worker lost; a line cut short by a crash is ignored on reading;
- ``results.csv``: one row per finished scenario sorted by index, rewritten atomically from
  the records (so it is the same whatever order, engine or run they came from).
"""
from __future__ import annotations

import csv
import io
import json
import os
from pathlib import Path

from swerve.core.atomic import write_text
from swerve.core.errors import ConfigError

from .scenario import Outcome, columns
from .spec import Campaign, parse_campaign_text

RECORDS = "records.jsonl"
RESULTS = "results.csv"
META = "campaign.json"
COPY = "campaign.yaml"


class Store:
    """The results folder of one campaign (see the module doc); ``open`` it with :meth:`open`."""

    def __init__(self, folder: Path, campaign: Campaign):
        self.folder, self.campaign = folder, campaign
        self.outcomes: dict[int, Outcome] = {}
        self.losses: dict[int, list[str]] = {}
        self._read_records()
        self._fh = None

    @classmethod
    def open(cls, folder: str | os.PathLike, campaign: Campaign) -> "Store":
        """Create ``folder`` for ``campaign``, or reopen it if it holds the same campaign file.

        Raises
        ------
        ConfigError
            If the folder holds another campaign's results, or files that are not a campaign's.
        """
        folder = Path(folder)
        meta = folder / META
        if meta.is_file():
            old = json.loads(meta.read_text(encoding="utf-8"))
            if old.get("sha256") != campaign.fingerprint:
                raise ConfigError(f"{folder} holds the results of another campaign file ({old.get('file')}); "
                                  f"resume with that file or choose another --out")
        elif folder.exists() and (not folder.is_dir() or any(folder.iterdir())):
            raise ConfigError(f"{folder} exists and is not an empty folder or a campaign's results: "
                              "choose another --out")
        else:
            write_text(folder / COPY, campaign.text)
            write_text(meta, json.dumps(dict(name=campaign.name, file=str(campaign.file),
                                             base=str(campaign.file.parent.resolve()),
                                             sha256=campaign.fingerprint), indent=2) + "\n")
        return cls(folder, campaign)

    def _read_records(self) -> None:
        path = self.folder / RECORDS
        if not path.is_file():
            return
        for line in path.read_text(encoding="utf-8").splitlines():
            try:
                rec = json.loads(line)
                index = int(rec["index"])
            except (ValueError, KeyError, TypeError):
                continue                # the last line of a run that was killed while writing it
            if "lost" in rec:
                self.losses.setdefault(index, []).append(str(rec["lost"]))
            else:
                self.outcomes[index] = Outcome(index, dict(rec["row"]), float(rec.get("run_s", 0.0)))

    def _append(self, rec: dict) -> None:
        if self._fh is None:
            self.folder.mkdir(parents=True, exist_ok=True)
            self._fh = open(self.folder / RECORDS, "a", encoding="utf-8")
            if self._fh.tell() and not (self.folder / RECORDS).read_bytes().endswith(b"\n"):
                self._fh.write("\n")        # close a line cut short by a crash
        self._fh.write(json.dumps(rec, sort_keys=True) + "\n")
        self._fh.flush()
        os.fsync(self._fh.fileno())

    def add(self, outcome: Outcome) -> None:
        """Keep a finished scenario (on disk before this returns)."""
        self._append(dict(index=outcome.index, row=outcome.row, run_s=outcome.run_s))
        self.outcomes[outcome.index] = outcome

    def lose(self, index: int, reason: str) -> int:
        """Note that scenario ``index``'s worker was lost; returns how many times it was."""
        self._append(dict(index=index, lost=reason))
        self.losses.setdefault(index, []).append(reason)
        return len(self.losses[index])

    def missing(self) -> list[int]:
        """Indices of the campaign's scenarios not finished yet, in order."""
        return [i for i in range(self.campaign.scenarios) if i not in self.outcomes]

    def rows(self) -> list[dict]:
        """The finished rows of this campaign (``--samples`` may have shrunk it), by index, with
        every column of results.csv (empty where a row has no value)."""
        head = columns(self.campaign)
        return [{c: self.outcomes[i].row.get(c, "") for c in head}
                for i in sorted(self.outcomes) if i < self.campaign.scenarios]

    def write_results(self) -> Path:
        """Rewrite ``results.csv`` (atomically) from the finished scenarios."""
        head = columns(self.campaign)
        buf = io.StringIO()
        w = csv.DictWriter(buf, head, lineterminator="\n")
        w.writeheader()
        w.writerows(self.rows())
        return write_text(self.folder / RESULTS, buf.getvalue(), fsync=False)

    def close(self) -> None:
        """Close the records file."""
        if self._fh is not None:
            self._fh.close()
            self._fh = None


def load_folder(folder: str | os.PathLike) -> Campaign:
    """The campaign whose results ``folder`` holds (its stored file, paths resolved where the
    original was)."""
    folder = Path(folder)
    try:
        meta = json.loads((folder / META).read_text(encoding="utf-8"))
        text = (folder / COPY).read_text(encoding="utf-8")
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{folder} is not a campaign's results folder ({exc})") from None
    return parse_campaign_text(text, Path(meta["file"]).name, Path(meta["base"]))


def read_results(folder: str | os.PathLike) -> list[dict]:
    """The rows of ``folder/results.csv``."""
    with open(Path(folder) / RESULTS, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


__all__ = ["RESULTS", "Store", "load_folder", "read_results"]
