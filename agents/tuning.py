"""Tuned baselines: each protocol's best declared setting, chosen on tuning episodes only.

The candidates of a protocol are the grid of its tunable parameters (``Parameter.grid`` values
over each declared range, all their combinations); settings written explicitly
(``greedy:lookahead=true``) stay fixed. Every candidate runs on the same tuning episodes (a
paired comparison, run like ``excite compare`` in the folder ``TUNED.tuning/`` beside the
output, so an interrupted tuning re-run with the same command continues); a protocol's
winner is its candidate with the lowest median, over the episodes, of the final max relative
error of r_L, r_R and b (ties: the one that changes fewest defaults, then the first in grid
order: a parameter that makes no difference keeps its default).

Tuning episodes draw their seeds from the ``tuning`` stream of
:func:`agents.compare.episode_seed`, whose seeds are never evaluation seeds (2**32 and above,
evaluation seeds lie below), whatever ``--seed`` and the episode counts: settings are never
chosen on an evaluation episode. The tuned file records its seeds; ``excite compare --tuned``
checks them against its own.
"""

from __future__ import annotations

import itertools
import json
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from agents.backends import LOCAL
from agents.catalog import ProtocolSpec
from agents.compare import (
    TUNING_STREAM,
    CompareSettings,
    columns_of,
    episode_seeds,
    run_comparison,
    settings_dict,
)
from agents.protocols import ProtocolError
from agents.segment_record import final_max_errors
from excite.errors import ExciteError

#: Version of the tuned-settings file format.
TUNED_FORMAT = 1
#: Where the package keeps the tuned settings of its registered envs (per robot preset).
SHIPPED_DIR = Path(__file__).parent / "tuned"
CRITERION = ("lowest median over the tuning episodes of the final max relative error of "
             "r_L, r_R, b")


class TunedError(ExciteError, ValueError):
    """A tuned-settings file that cannot be read, or that does not fit the comparison."""


def candidates(spec: ProtocolSpec) -> list[ProtocolSpec]:
    """Every combination of the tuning values of the parameters ``spec`` leaves unset, each
    written with the values that differ from the defaults (so the candidate at the defaults is
    ``spec`` itself, and labels stay short)."""
    given = dict(spec.settings)
    free = [p for p in spec.protocol.parameters if p.grid and p.name not in given]
    grids = itertools.product(*(p.tuning_values() for p in free))
    return [spec.under({p.name: v for p, v in zip(free, values, strict=True) if v != p.default})
            for values in grids]


def work_dir(out: str | Path) -> Path:
    """The folder beside ``out`` (``TUNED.json``) that holds the tuning episodes."""
    return Path(out).with_suffix(".tuning")


def shipped_path(env_id: str, robot: str = "default") -> Path:
    """The package's tuned-settings file of an env id and robot preset (it may not exist):
    ``excite_ID.json`` for the default robot, ``excite_ID.PRESET.json`` for another."""
    stem = env_id.replace("/", "_")
    return SHIPPED_DIR / (f"{stem}.json" if robot == "default" else f"{stem}.{robot}.json")


def select(columns: Mapping[str, np.ndarray], spec: ProtocolSpec,
           tried: Sequence[ProtocolSpec]) -> dict:
    """The tuned entry of ``spec``: the winner among the candidates ``tried``, its median
    final max error (relative), that of ``spec``'s defaults (None when not on the grid) and
    that of every candidate."""
    medians = [float(np.median(final_max_errors(columns, c.label))) for c in tried]
    defaults = spec.resolved()
    resolved = [c.resolved() for c in tried]
    at_defaults = [m for r, m in zip(resolved, medians, strict=True) if r == defaults]
    changed = [sum(r[k] != defaults[k] for k in r) for r in resolved]
    best = min(range(len(tried)), key=lambda i: (medians[i], changed[i], i))
    return {
        "settings": dict(tried[best].settings),
        "label": tried[best].label,
        "final_max_error": medians[best],
        "default_final_max_error": at_defaults[0] if at_defaults else None,
        "candidates": [{"settings": dict(c.settings), "final_max_error": m}
                       for c, m in zip(tried, medians, strict=True)],
    }


def run_tuning(out: str | Path, specs: Sequence[ProtocolSpec], episodes: int,
               settings: CompareSettings, workers: int | None = None,
               progress: bool = True, backend: str = LOCAL,
               address: str | None = None) -> dict:
    """Tune every protocol of ``specs`` on ``episodes`` tuning episodes of ``settings`` (its
    seed stream is replaced by the tuning stream); writes and returns the tuned document
    (``out``, JSON). Resumable: the episodes live in :func:`work_dir`. The episodes run on
    ``backend`` at ``address`` (see :func:`agents.compare.run_comparison`)."""
    settings = replace(settings, stream=TUNING_STREAM, final_only=True)
    tried = {spec.label: candidates(spec) for spec in specs}
    unique = list(dict.fromkeys(c for group in tried.values() for c in group))
    rows = run_comparison(work_dir(out), unique, episodes, settings, workers, progress,
                          backend=backend, address=address)
    columns = columns_of(rows)
    document = {
        "excite_tuned": TUNED_FORMAT,
        **settings_dict(settings),
        "episodes": episodes,
        "tuning_seeds": episode_seeds(settings, episodes),
        "criterion": CRITERION,
        "protocols": {spec.label: select(columns, spec, tried[spec.label]) for spec in specs},
    }
    _write_json(Path(out), document)
    return document


def _write_json(path: Path, document: dict) -> None:
    """Write ``document`` to ``path`` atomically (a reader never sees half a file)."""
    partial = path.with_name(path.name + ".partial")
    partial.write_text(json.dumps(document, indent=2, allow_nan=False) + "\n")
    os.replace(partial, path)


def load_tuned(path: str | Path) -> dict:
    """A tuned-settings file written by :func:`run_tuning`, checked for the keys a
    comparison uses."""
    try:
        document = json.loads(Path(path).read_text())
    except OSError as exc:
        raise TunedError(f"cannot read tuned settings {path}: {exc.strerror}") from None
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError):
        raise TunedError(f"{path}: not valid JSON") from None
    required = {"excite_tuned": int, "env_id": str, "segments": int, "robot": str,
                "tuning_seeds": list, "protocols": dict}
    if not isinstance(document, dict) or any(
            not isinstance(document.get(key), kind) for key, kind in required.items()):
        raise TunedError(f"{path}: not a tuned-settings file of excite tune (it needs "
                         f"{', '.join(required)})")
    if document["excite_tuned"] != TUNED_FORMAT:
        raise TunedError(f"{path}: tuned-settings format {document['excite_tuned']}, this "
                         f"excite reads format {TUNED_FORMAT}; re-run excite tune")
    for label, entry in document["protocols"].items():
        if not (isinstance(entry, dict) and isinstance(entry.get("settings"), dict)):
            raise TunedError(f"{path}: protocol {label!r} has no settings")
    if not all(isinstance(seed, int) and not isinstance(seed, bool)
               for seed in document["tuning_seeds"]):
        raise TunedError(f"{path}: tuning_seeds must be a list of integers (episode seeds)")
    return document


def mismatch(document: Mapping, settings: CompareSettings) -> str | None:
    """How the episodes a tuned document was tuned on differ from those of ``settings`` (a
    comparison's or a simulation's: env, segments, robot), in words; None when they agree."""
    tuned = (document["env_id"], document["segments"], document["robot"])
    wanted = (settings.env_id, settings.segments, settings.robot)
    if tuned == wanted:
        return None
    return (f"tuned for {tuned[1]} segments of the {tuned[2]} robot on {tuned[0]}, this "
            f"run drives {wanted[1]} segments of the {wanted[2]} robot on {wanted[0]}")


def check_disjoint(document: Mapping, settings: CompareSettings, episodes: int) -> None:
    """TunedError if an evaluation episode of the comparison was a tuning episode."""
    shared = set(document["tuning_seeds"]) & set(episode_seeds(settings, episodes))
    if shared:
        raise TunedError(f"{len(shared)} of the comparison's episode seeds were tuning "
                         "episodes of the tuned settings; settings must be tuned on other "
                         "episodes")


def apply_tuned(specs: Iterable[ProtocolSpec], document: Mapping,
                origin: str) -> tuple[list[ProtocolSpec], list[str]]:
    """Each spec with its tuned settings (the document's entry of the same label; settings
    written explicitly win), and the labels of the specs the document does not tune.
    ``origin`` names the document in errors."""
    tuned, untuned = [], []
    for spec in specs:
        entry = document["protocols"].get(spec.label)
        if entry is None:
            untuned.append(spec.label)
            tuned.append(spec)
            continue
        try:
            tuned.append(spec.under(entry["settings"]))
        except ProtocolError as exc:
            raise TunedError(f"{origin}: the tuned settings of {spec.label}: {exc}") from None
    return tuned, untuned
