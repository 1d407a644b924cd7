"""A run directory, loaded one way: what `ropemon evaluate`, the population and the demo
leave of one simulated wind, read by the evaluation and the studies (`ropemon study`).

    RUN/sim/            the simulator's output (`ropemon simulate --out` writes the same
                        files into its directory, which may be RUN itself):
        truth.npz       truth arrays at the sample times (docs/simulator.md)
        truth.json      scenario, hidden plant, phases, the simulator's `physical` (`meta`)
        sensors.rsens   the node's inputs (docs/data-formats.md)
        node.json       the config those sensors were made with
    RUN/node-evaluated.json   the config the evaluation commissioned (`ropemon evaluate`; not
                              written where the node refuses it)
    RUN/frames.bin            the firmware's radio bytes (`ropemon replay`)
    RUN/frames-baseline.bin, RUN/node-baseline.json   the population's baseline node

Everything is read when first used and kept; the truth one array at a time (a duty
cycle's truth is hundreds of MB).
"""
from __future__ import annotations

import copy
import json
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from ropemon.station import files

NODE_EVALUATED = "node-evaluated.json"  # the commissioned config, in the scenario's run directory


class RunDirError(ValueError):
    """A run directory's file that cannot be read: the message names the file and the reason."""
FRAMES = "frames.bin"


class Truth(Mapping):
    """truth.npz's arrays by name, each read from the file when first used; `cut(k)`: the
    same arrays' first k samples."""

    def __init__(self, path: Path):
        self.path = Path(path)
        files.check_file(self.path, "truth", None, RunDirError)  # no FIFO, no device
        try:
            with np.load(self.path) as z:
                self._names = tuple(z.files)
        except (OSError, ValueError, zipfile.BadZipFile, EOFError) as e:
            raise RunDirError(f"{self.path}: not a truth.npz: {e}") from None
        self._arrays: dict[str, np.ndarray] = {}
        self.samples: int | None = None

    def __getitem__(self, name: str) -> np.ndarray:
        if name not in self._arrays:
            if name not in self._names:
                raise KeyError(name)
            with np.load(self.path) as z:
                self._arrays[name] = z[name]
        a = self._arrays[name]
        return a if self.samples is None or not np.ndim(a) else a[: self.samples]

    def cut(self, samples: int) -> Truth:
        """A view of the first `samples` samples (sharing what has been read)."""
        view = copy.copy(self)
        view.samples = samples
        return view

    def __iter__(self):
        return iter(self._names)

    def __len__(self) -> int:
        return len(self._names)


@dataclass
class Scoring:
    """A run's truth as every figure is scored (`evaluate.scoring_masks`), over `length` samples."""

    truth_n: np.ndarray      # (samples, ropes) true rope tensions
    phase: np.ndarray        # index into metrics.PHASES
    excluded: np.ndarray     # within the hold after a shock
    steady: np.ndarray       # payload not being changed
    payload_kg: np.ndarray
    rated_n: float
    sample_hz: int


def decode_frames(path: Path, keys: dict[int, bytes]):
    """(data frames in sequence order, the decoder's counts) of a radio byte file, decoded
    with `keys` (node id -> key: a node.json's node section, `identity`)."""
    from ropemon.station.decoder import StreamDecoder

    dec = StreamDecoder(dict(keys))
    frames = [f for f in dec.feed(files.read_bytes(path, "radio bytes", files.MAX_FRAMES_BIN, RunDirError)) if f.ropes]
    frames.sort(key=lambda f: f.seq)
    return frames, dec.counts


@dataclass
class RunDir:
    """One run directory (module doc): its paths, and what they hold, read when first used."""

    path: Path

    def __post_init__(self):
        self.path = Path(self.path)

    @property
    def sim(self) -> Path:
        """The simulator's directory: RUN/sim, or RUN itself when it holds the truth."""
        return self.path if (self.path / "truth.json").exists() else self.path / "sim"

    @property
    def truth_path(self) -> Path:
        return self.sim / "truth.npz"

    @property
    def sensors_path(self) -> Path:
        return self.sim / "sensors.rsens"

    @property
    def config_path(self) -> Path:
        return self.path / NODE_EVALUATED

    @cached_property
    def meta(self) -> dict:
        """truth.json: the scenario, the hidden plant, the phases, the simulator's config."""
        return files.read_json(self.sim / "truth.json", "truth.json", files.MAX_RUN_JSON, RunDirError, allow_nan=True)

    @cached_property
    def truth(self) -> Truth:
        return Truth(self.truth_path)

    @cached_property
    def _sensors(self) -> tuple[int, int, np.ndarray]:
        from ropemon.commission.reference import read_rsens

        return read_rsens(self.sensors_path)

    @property
    def records(self) -> np.ndarray:
        """sensors.rsens's records [sample, 2N+4] (uint16 words), all of them."""
        return self._sensors[2]

    @property
    def sample_hz(self) -> int:
        """The sensor stream's sample rate (truth.json's where the run has no stream)."""
        return self._sensors[1] if self.sensors_path.exists() else int(self.meta["sample_hz"])

    @property
    def length(self) -> int:
        """Samples that have both a record and a truth."""
        return min(len(self.records), len(self.truth["tension_N"]))

    @cached_property
    def config(self) -> dict:
        """The node.json the evaluation commissioned (node-evaluated.json). The simulator's own
        config is `meta["node_physical"]` (and sim/node.json)."""
        if not self.config_path.exists():
            raise FileNotFoundError(f"{self.config_path}: no commissioned config (not a run of `ropemon evaluate`, "
                                    "or its node refused the config)")
        return files.read_json(self.config_path, "commissioned config", files.MAX_NODE_JSON, RunDirError, allow_nan=True)

    @property
    def physical(self) -> dict:
        """The config's `physical` section, a copy the caller may change."""
        return copy.deepcopy(self.config["physical"])

    @property
    def identity(self) -> dict:
        """The node's id and key as `make_node_json` takes them (`node_id=`, `key=`): those of
        the simulator's node.json (the scenario site's), which the lab's configs of this run keep."""
        nd = json.loads((self.sim / "node.json").read_text())["node"]
        return {"node_id": int(nd["node_id"]), "key": bytes(nd["key"])}

    @property
    def keys(self) -> dict[int, bytes]:
        """node id -> key of the commissioned config (its node section: the copy the node reads)."""
        nd = self.config["node"]
        return {int(nd["node_id"]): bytes(nd["key"])}

    def frames(self, name: str = FRAMES) -> list:
        """The data frames of RUN/name, in sequence order, decoded with the config's key."""
        return decode_frames(self.path / name, self.keys)[0]

    def scoring(self, physical: dict | None = None) -> Scoring:
        """The scoring masks of the run's first `length` samples, with the rated tension and
        shaft depth of `physical` (default: the config's)."""
        from ropemon.lab.evaluate import scoring_masks

        ph = physical or self.config["physical"]
        rated = float(ph["rated_rope_tension_N"])
        truth_n = np.asarray(self.truth["tension_N"], float)[: self.length]
        phase, excluded, steady, payload = scoring_masks(self.truth, truth_n, self.sample_hz, rated,
                                                         float(ph["hall_marks_m"][-1]))
        return Scoring(truth_n, phase, excluded, steady, payload, rated, self.sample_hz)
