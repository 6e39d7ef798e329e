"""Where AOC/DHP weights of a line come from: shipped, cached, or trained now (ROS-free).

Weights belong to a line: a weights file records the traffic-model hash
of the line it was trained on (:func:`metro_atc.core.atr.fingerprint.line_hash`) and
:func:`metro_atc.core.atr.regulators.load_weights` refuses it on any other line.
:func:`find_weights` looks for weights of a line among the shipped files
(``metro_atc/data/<kind>_*.pt``) and in the cache directory, where
:func:`ensure_weights` writes the weights it trains:

    ${METRO_ATC_ATR_CACHE:-${XDG_CACHE_HOME:-~/.cache}/metro_atc/atr}/<hash>-<kind>.pt

Training uses the standard configuration of the shipped weights
(:func:`metro_atc.core.atr.training.atr_train_config`, seed 0, one CPU thread) and is
validated on the truth traffic model before it is cached: the trained regulator and the
timetable (``none``) regulate the same episodes (180 s initial delay at the first station,
the line's exponential departure delays); the costs are recorded in the file's ``info``
(``validation``).
"""

from __future__ import annotations

import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Dict, Optional

import numpy as np
import torch

from metro_atc.core.atr.blue_line import LineData
from metro_atc.core.atr.cost import CostWeights
from metro_atc.core.atr.evaluation import incident_scenario, kpis, simulate
from metro_atc.core.atr.fingerprint import line_hash
from metro_atc.core.atr.problems import AtrProblem
from metro_atc.core.atr.registry import TRAINED
from metro_atc.core.atr.regulators import (DATA_DIR, NeuralRegulator, NoneRegulator, Regulator,
                                           read_blob, save_weights, shipped_weights,
                                           weights_match)
from metro_atc.core.atr.training import atr_train_config, train

KINDS = TRAINED
"""Regulators whose weights the store keeps (:data:`metro_atc.core.atr.registry.TRAINED`)."""
CACHE_ENV = "METRO_ATC_ATR_CACHE"
"""Environment variable overriding the cache directory."""
DEFAULT_EPOCHS = 1500
"""Epochs of a training (the shipped weights' setting)."""
VALIDATION_DELAY_S = 180.0
VALIDATION_EPISODES = 8

Progress = Callable[[str], None]


def cache_dir() -> Path:
    """The cache directory of trained weights (module docstring)."""
    env = os.environ.get(CACHE_ENV, "")
    if env:
        return Path(env).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME", "")
    base = Path(xdg).expanduser() if xdg else Path.home() / ".cache"
    return base / "metro_atc" / "atr"


def cached_path(kind: str, line: LineData, directory: Optional[Path] = None) -> Path:
    """Cache file of ``kind`` weights for ``line``: ``<dir>/<hash>-<kind>.pt``."""
    _check_kind(kind)
    return (directory if directory is not None else cache_dir()) / f"{line_hash(line)}-{kind}.pt"


def _check_kind(kind: str) -> None:
    if kind not in KINDS:
        raise ValueError(f"weights kind must be one of {', '.join(KINDS)}, got {kind!r}")


def find_weights(kind: str, line: LineData, cache: Optional[Path] = None,
                 shipped: Optional[Path] = None) -> Optional[Path]:
    """Weights of ``kind`` trained on ``line`` (same traffic-model hash), or None.

    Looks at the shipped files (:func:`shipped_weights`) first, then the cache file.
    """
    found = shipped_weights(kind, line, shipped)
    if found is not None:
        return found
    c = cached_path(kind, line, cache)
    return c if c.is_file() and weights_match(c, kind, line_hash(line)) else None


def validate(line: LineData, regulator: Regulator, weights: CostWeights,
             episodes: int = VALIDATION_EPISODES) -> Dict[str, float]:
    """Mean realised cost of ``regulator`` and of ``none`` on the truth traffic model.

    Episodes: ``VALIDATION_DELAY_S`` at the first station, exponential departure delays
    (seeds 0 .. episodes-1, the same for both), K + N stages.  Returns the mean costs
    (Lin 2010a, eq. 17 realised, :func:`metro_atc.core.atr.evaluation.kpis`) and their ratio.
    """
    problem = AtrProblem(line, weights)
    steps = weights.horizon + line.n_stations
    none = NoneRegulator(line.n_stations)
    c_reg: list[float] = []
    c_none: list[float] = []
    for s in range(episodes):
        sc = incident_scenario(line, VALIDATION_DELAY_S, s, steps)
        for reg, acc in ((regulator, c_reg), (none, c_none)):
            traj = simulate(line, reg, sc["x0"], sc["w"], weights.horizon)
            acc.append(kpis(traj, line, weights, problem.p0_np)["cost"])
    cr, cn = float(np.mean(c_reg)), float(np.mean(c_none))
    return {"cost": cr, "cost_none": cn, "ratio_to_none": cr / cn if cn > 0 else float("nan"),
            "episodes": episodes, "delay_s": VALIDATION_DELAY_S}


def train_weights(kind: str, line: LineData, out: Path, epochs: int = DEFAULT_EPOCHS,
                  seed: int = 0, weights: Optional[CostWeights] = None,
                  progress: Optional[Progress] = None,
                  extra_info: Optional[Dict[str, Any]] = None) -> Dict[str, Any]:
    """Train ``kind`` on ``line``, validate, write ``out`` atomically; returns the info dict.

    ``extra_info`` (plain JSON values) is added to the file's ``info``.
    """
    _check_kind(kind)
    if epochs < 1:
        raise ValueError(f"epochs must be >= 1, got {epochs}")
    w = weights if weights is not None else CostWeights()
    problem = AtrProblem(line, w)
    say = progress if progress is not None else (lambda _msg: None)
    step = max(1, epochs // 20)

    def tick(done: int, total: int, cost: float, elapsed: float) -> None:
        if done % step == 0 or done == total:
            eta = elapsed / done * (total - done)
            say(f"training {kind} for line {line.name!r}: epoch {done}/{total}, cost "
                f"{cost:.1f}, {elapsed:.0f} s, ETA {eta:.0f} s")

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        res = train(kind, problem, atr_train_config(seed, epochs), progress=tick)
    finally:
        torch.set_num_threads(threads)
    agent = res.agent(problem)
    check = validate(line, NeuralRegulator(agent, problem), w)
    say(f"trained {kind} for line {line.name!r} in {res.seconds:.0f} s: cost on the traffic "
        f"model {check['cost']:.1f} vs timetable {check['cost_none']:.1f} "
        f"(ratio {check['ratio_to_none']:.3f}, {VALIDATION_DELAY_S:.0f} s initial delay)")
    info = {"seed": seed, "epochs": epochs, "train_seconds": round(res.seconds, 2),
            "final_cost": res.history["cost"][-1], "torch": str(torch.__version__),
            "validation": check, "trained_at": time.strftime("%Y-%m-%dT%H:%M:%SZ",
                                                             time.gmtime()),
            **(extra_info or {})}
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=str(out.parent), prefix=f".{out.name}.", suffix=".tmp")
    os.close(fd)
    try:
        save_weights(tmp, agent, line, w, info)
        os.replace(tmp, out)  # readers never see a half-written file
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return info


@dataclass(frozen=True)
class Resolved:
    """Weights resolved for a run: the file and where it came from."""

    path: Path
    source: str
    """``shipped`` (``metro_atc/data``), ``cached`` (trained earlier, in the cache) or
    ``trained`` (trained now into the cache)."""


def ensure_weights(kind: str, line: LineData, train_missing: bool = True,
                   cache: Optional[Path] = None, epochs: int = DEFAULT_EPOCHS,
                   progress: Optional[Progress] = None) -> Path:
    """Weights of ``kind`` for ``line``: shipped or cached, else trained into the cache.

    ``train_missing`` False: ValueError (one line, naming the hash and the command that
    trains them) instead of training.  :func:`resolve_weights` also says which it was.
    """
    return resolve_weights(kind, line, train_missing, cache, epochs, progress).path


def resolve_weights(kind: str, line: LineData, train_missing: bool = True,
                    cache: Optional[Path] = None, epochs: int = DEFAULT_EPOCHS,
                    progress: Optional[Progress] = None) -> Resolved:
    """:func:`ensure_weights` with the weights' source (shipped, cached, trained now)."""
    found = find_weights(kind, line, cache)
    if found is not None:
        ship = found.parent.resolve() == DATA_DIR.resolve()
        return Resolved(found, "shipped" if ship else "cached")
    target = cached_path(kind, line, cache)
    if not train_missing:
        raise ValueError(f"no {kind} weights for line {line.name!r} (traffic-model hash "
                         f"{line_hash(line)[:12]}; not shipped, not in {target.parent}): "
                         f"run with --train-regulator auto or train them with "
                         f"'python -m metro_atc train {kind} --scenario ... --cache'")
    train_weights(kind, line, target, epochs=epochs, progress=progress)
    return Resolved(target, "trained")


def validation_problem(path: Path) -> Optional[str]:
    """One line with the figures if the weights in ``path`` regulate worse than the timetable.

    Reads the file's own validation (``info.validation``, written by
    :func:`train_weights`: mean realised cost of the regulator and of the timetable on the
    same episodes); None when the regulator's cost is at most the timetable's, or when the
    file holds no validation (weights from elsewhere: nothing to judge by).
    """
    try:
        info = read_blob(path).get("info") or {}
    except (OSError, ValueError):
        return None
    v = info.get("validation") if isinstance(info, dict) else None
    if not isinstance(v, dict):
        return None
    try:
        cost, none = float(v["cost"]), float(v["cost_none"])
    except (KeyError, TypeError, ValueError):
        return None
    if not (np.isfinite(cost) and np.isfinite(none)) or cost <= none:
        return None
    return (f"{path.name}: its own validation cost {cost:.1f} is above the timetable's "
            f"{none:.1f} (ratio {cost / none if none > 0 else float('inf'):.3f}, "
            f"{int(v.get('episodes', 0))} episodes, {float(v.get('delay_s', 0.0)):.0f} s "
            "initial delay): it regulates worse than no regulator")
