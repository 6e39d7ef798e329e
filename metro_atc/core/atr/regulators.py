"""ATR regulators behind one interface: none (timetable), LQR, DHP, AOC (Lin 2010a, sec. 3-4).

All regulators map the staggered departure deviation x [s] (Lin 2010a, eq. 5 state minus the
timetable) to running/dwell-time adjustments u [s]: ``Regulator.decide(x, step)``.
``step`` is the stage index k within the finite number of adjustable services (the neural
regulators take the time-to-go (K - k)/K as input; the node uses step = 0, i.e. a receding
horizon).  Saturation is *not* applied here: the plant (or the node) limits the command.

- ``none``: u = 0 (run to the timetable).
- ``lqr``: u = -K x with K from the discrete algebraic Riccati equation of the linear model
  (A, B) with Q = q I, R = r I (``scipy.linalg.solve_discrete_are``); it assumes a linear,
  unconstrained plant (Lin 2010a, sec. 5: "The LQR method assumes linear model ...").
- ``dhp`` / ``aoc``: trained critic-actor MLPs (:mod:`metro_atc.core.atr.training`), loaded
  from a weights file written by ``python -m metro_atc train``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Dict, Optional, Union

import numpy as np

from metro_atc.core.atr.blue_line import LineData
from metro_atc.core.atr.cost import CostWeights
from metro_atc.core.atr.fingerprint import line_hash
from metro_atc.core.atr.registry import REGULATORS, TRAINED
from metro_atc.core.atr.traffic import linear_model

if TYPE_CHECKING:
    from metro_atc.core.atr.problems import AtrProblem
    from metro_atc.core.atr.training import Agent
    from metro_atc.core.line.scenario import Scenario

# torch (~2 s of CPU to import) and scipy.linalg are imported by the regulators that use
# them, not here: the ATS node with the default regulator 'none' loads neither
# (test/test_startup_imports.py)

WEIGHTS_FORMAT = "metro_atc.atr.weights/1"
MAX_WEIGHTS_BYTES = 50_000_000
"""Largest ATR weights file read [bytes] (the shipped ones are < 100 kB)."""
DATA_DIR = Path(__file__).resolve().parents[2] / "data"


def lqr_gain(a: np.ndarray, b: np.ndarray, q: float, r: float) -> np.ndarray:
    """Infinite-horizon discrete LQR gain K (u = -K x) for U = 1/2 q|x|^2 + 1/2 r|u|^2."""
    from scipy.linalg import solve_discrete_are
    n, m = a.shape[0], b.shape[1]
    p = solve_discrete_are(a, b, q * np.eye(n), r * np.eye(m))
    return np.linalg.solve(r * np.eye(m) + b.T @ p @ b, b.T @ p @ a)


class Regulator:
    """Common interface: ``decide(x, step)`` -> adjustments u [s] (same shape as x)."""

    name = "base"

    def __init__(self, n_stations: int) -> None:
        """Store the state dimension."""
        self.n = n_stations

    def _check(self, x_s: np.ndarray) -> np.ndarray:
        x = np.asarray(x_s, dtype=float)
        if x.shape[-1] != self.n:
            raise ValueError(f"state has {x.shape[-1]} entries, the line has {self.n} stations")
        if not np.all(np.isfinite(x)):
            raise ValueError("state contains NaN or inf")
        return x

    def decide(self, x_s: np.ndarray, step: int = 0) -> np.ndarray:
        """Adjustments u [s] for deviations x [s] (shape (N,) or (B, N)) at stage ``step``."""
        raise NotImplementedError


class NoneRegulator(Regulator):
    """Timetable operation: no adjustment."""

    name = "none"

    def decide(self, x_s: np.ndarray, step: int = 0) -> np.ndarray:
        """Return zeros."""
        return np.zeros_like(self._check(x_s))


class LqrRegulator(Regulator):
    """Linear-quadratic regulator on the approximate (linear) traffic model."""

    name = "lqr"

    def __init__(self, a: np.ndarray, b: np.ndarray, weights: CostWeights) -> None:
        """Solve the DARE in scaled units (the scaling cancels in the linear gain)."""
        super().__init__(a.shape[0])
        self.k = lqr_gain(a, b, weights.q, weights.r)

    def decide(self, x_s: np.ndarray, step: int = 0) -> np.ndarray:
        """u = -K x."""
        return -(self._check(x_s) @ self.k.T)


class NeuralRegulator(Regulator):
    """DHP or AOC policy (AOC: u = actor(x, critic(x)), Lin 2010a, eq. 49; DHP: u = actor(x))."""

    def __init__(self, agent: Agent, problem: AtrProblem,
                 meta: Optional[Dict[str, Any]] = None) -> None:
        """Wrap a trained agent acting on ``problem``'s scaled state."""
        super().__init__(problem.nx)
        self.agent, self.problem = agent, problem
        self.name = agent.method
        self.meta = dict(meta or {})
        self._xs = problem.w.x_scale_s

    def decide(self, x_s: np.ndarray, step: int = 0) -> np.ndarray:
        """Policy output in seconds (no gradient tape)."""
        import torch
        x = self._check(x_s)
        batch = x.reshape(-1, self.n) / self._xs
        tau = max(self.problem.horizon - int(step), 0) / self.problem.horizon
        xt = torch.from_numpy(np.ascontiguousarray(batch))
        extra = torch.full((xt.shape[0], 1), tau, dtype=torch.float64)
        with torch.no_grad():
            u = self.agent.act(xt, extra).numpy() * self._xs
        return u.reshape(x.shape)


def save_weights(path: Union[str, Path], agent: Agent, line: LineData, weights: CostWeights,
                 info: Optional[Dict[str, Any]] = None) -> None:
    """Write a trained agent (small .pt file: dict of tensors and plain values).

    The file records the traffic-model hash of ``line``
    (:func:`metro_atc.core.atr.fingerprint.line_hash`): :func:`load_weights` refuses it on
    any other line.
    """
    import torch
    blob = {
        "format": WEIGHTS_FORMAT,
        "method": agent.method,
        "scenario": line.name,
        "n_stations": line.n_stations,
        "line_hash": line_hash(line),
        "cost": {"q": weights.q, "r": weights.r, "x_scale_s": weights.x_scale_s,
                 "horizon": weights.horizon},
        "critic": agent.critic.state(),
        "actor": agent.actor.state(),
        "anchored": agent.anchored,
        # plain JSON types only, so that torch.load(weights_only=True) accepts the file
        "info": json.loads(json.dumps(dict(info or {}), default=str)),
    }
    torch.save(blob, str(path))


def read_blob(path: Union[str, Path]) -> Dict[str, Any]:
    """The dict of an ATR weights file, read safely (size limit, ``weights_only=True``).

    Raises FileNotFoundError or ValueError (one line) for a missing, oversized, unreadable
    or foreign file; the networks are not checked here (:func:`load_weights` does).
    """
    import torch
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"ATR weights file not found: {p}")
    if p.stat().st_size > MAX_WEIGHTS_BYTES:
        raise ValueError(f"{p}: {p.stat().st_size} bytes, larger than the limit of "
                         f"{MAX_WEIGHTS_BYTES} bytes for an ATR weights file")
    try:
        blob = torch.load(str(p), weights_only=True)
    except Exception as exc:  # noqa: BLE001 - torch raises many types for bad files
        text = " ".join(str(exc).split())[:100]
        raise ValueError(f"cannot read ATR weights file {p}: {text}") from None
    if not isinstance(blob, dict) or blob.get("format") != WEIGHTS_FORMAT:
        raise ValueError(f"{p} is not an ATR weights file ({WEIGHTS_FORMAT})")
    return blob


def load_weights(path: Union[str, Path], line: LineData) -> NeuralRegulator:
    """Load a weights file written by :func:`save_weights` for ``line`` (validated).

    Refuses (ValueError) a file trained on another line: its traffic-model hash must be
    ``line``'s.
    """
    from metro_atc.core.atr.mlp import MLP
    from metro_atc.core.atr.problems import AtrProblem
    from metro_atc.core.atr.training import Agent
    p = Path(path)
    blob = read_blob(p)
    if not isinstance(blob.get("n_stations"), int) or not isinstance(blob.get("cost"), dict):
        raise ValueError(f"{p}: malformed ATR weights file (n_stations or cost missing)")
    if int(blob["n_stations"]) != line.n_stations:
        raise ValueError(f"{p} was trained for {blob['n_stations']} stations, line "
                         f"{line.name!r} has {line.n_stations}")
    trained_on = blob.get("line_hash")
    if not isinstance(trained_on, str):
        raise ValueError(f"{p} records no traffic-model hash of its line (written before "
                         f"weights were tied to a line): retrain it")
    if trained_on != line_hash(line):
        raise ValueError(f"{p} was trained on another line (traffic-model hash "
                         f"{trained_on[:12]}, scenario {blob.get('scenario')!r}); line "
                         f"{line.name!r} has hash {line_hash(line)[:12]}")
    try:
        c = blob["cost"]
        weights = CostWeights(q=float(c["q"]), r=float(c["r"]),
                              x_scale_s=float(c["x_scale_s"]), horizon=int(c["horizon"]))
        problem = AtrProblem(line, weights)
        agent = Agent(str(blob["method"]), problem, MLP.from_state(blob["critic"]),
                      MLP.from_state(blob["actor"]), anchored=bool(blob.get("anchored", False)))
    except (KeyError, TypeError, ValueError, AttributeError, IndexError, RuntimeError,
            OverflowError) as exc:
        raise ValueError(f"{p}: malformed ATR weights file ({type(exc).__name__}: "
                         f"{str(exc)[:80]})") from None
    n_ci = problem.nx + problem.n_extra
    n_ai = n_ci + (problem.nx if agent.method == "aoc" else 0)
    if agent.critic.n_in != n_ci or agent.actor.n_in != n_ai:
        raise ValueError(f"{p}: network sizes do not match the line")
    return NeuralRegulator(agent, problem, {"path": str(p), "scenario": blob["scenario"],
                                            "cost": c, "info": blob.get("info", {})})


def default_weights_path(method: str, scenario: str) -> Path:
    """Path of the shipped default weights for ``method`` on ``scenario``."""
    return DATA_DIR / f"{method}_{scenario}.pt"


@dataclass(frozen=True)
class RegulatorInputs:
    """What a regulator factory of :data:`metro_atc.core.atr.registry.REGULATORS` gets.

    line: the ATR line; cost: the cost weights (q, r, x_scale_s, horizon); weights_path:
    trained regulators' weights file (None: the shipped file for the line); scenario: the
    scenario (the energy-aware LQR builds its energy table from it; None elsewhere);
    energy_weight: the energy-aware LQR's weight w_E [-].
    """

    line: LineData
    cost: CostWeights
    weights_path: Optional[Path] = None
    scenario: Optional["Scenario"] = None
    energy_weight: float = 1.0


def build_none(name: str, inputs: RegulatorInputs) -> Regulator:
    """Factory of ``none``: the timetable (u = 0)."""
    return NoneRegulator(inputs.line.n_stations)


def build_lqr(name: str, inputs: RegulatorInputs) -> Regulator:
    """Factory of ``lqr``: the gain of the line's linear traffic model."""
    a, b = linear_model(inputs.line.c())  # AtrProblem's a_np, b_np without its torch tensors
    return LqrRegulator(a, b, inputs.cost)


def build_trained(name: str, inputs: RegulatorInputs) -> Regulator:
    """Factory of the trained regulators (``dhp``, ``aoc``): load and check the weights.

    The file (default: the shipped weights trained on the line, found by its traffic-model
    hash, :func:`shipped_weights`; none: the file named
    after the line, refused or missing) must hold a ``name`` policy trained on this line;
    its cost weights and horizon come from the file.
    """
    path = inputs.weights_path
    if path is None:
        path = shipped_weights(name, inputs.line) or default_weights_path(name,
                                                                          inputs.line.name)
    reg = load_weights(path, inputs.line)
    if reg.name != name:
        raise ValueError(f"{path} holds a {reg.name!r} regulator, not {name!r}")
    return reg


def make_regulator(name: str, line: LineData, weights: Optional[CostWeights] = None,
                   weights_path: Optional[Union[str, Path]] = None,
                   scenario: Optional["Scenario"] = None,
                   energy_weight: float = 1.0) -> Regulator:
    """Build a regulator by name (:data:`metro_atc.core.atr.registry.REGULATORS`).

    For dhp/aoc, ``weights_path`` defaults to the shipped weights for the line (if any);
    the cost weights and horizon then come from the file.  ``elqr`` needs ``scenario``
    (its energy table) and takes ``energy_weight``.  ValueError (one line) for an unknown
    name or a regulator that cannot be built.
    """
    entry = REGULATORS.entry(name)
    w = weights if weights is not None else CostWeights()
    inputs = RegulatorInputs(line, w, Path(weights_path) if weights_path is not None else None,
                             scenario, float(energy_weight))
    reg: Regulator = entry.load()(name, inputs)
    return reg


def weights_match(path: Path, kind: str, digest: str) -> bool:
    """Whether ``path`` is a readable weights file of ``kind`` for the hash ``digest``."""
    try:
        blob = read_blob(path)
    except (OSError, ValueError):
        return False
    return blob.get("method") == kind and blob.get("line_hash") == digest


def shipped_weights(kind: str, line: LineData, shipped: Optional[Path] = None
                    ) -> Optional[Path]:
    """The shipped file ``<shipped>/<kind>_*.pt`` trained on ``line`` (its hash), or None.

    Shipped files are named per line and direction (``aoc_taipei_blue.pt``,
    ``aoc_taipei_blue_down.pt``); the hash inside, not the name, decides.
    """
    if kind not in TRAINED:
        raise ValueError(f"weights kind must be one of {', '.join(TRAINED)}, got {kind!r}")
    digest = line_hash(line)
    ship = shipped if shipped is not None else DATA_DIR
    for p in sorted(ship.glob(f"{kind}_*.pt")):
        if weights_match(p, kind, digest):
            return p
    return None
