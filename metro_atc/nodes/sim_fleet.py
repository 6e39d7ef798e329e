"""The line_simulator's lockstep carrier: the fleet state, the per-train states and /clock.

Every lockstep step the simulator publishes one ``/line/fleet_state`` (CDR bytes built from
a cached layout per list of active trains), the ``/<train>/state`` of the trains that need
one (every ``state_every`` steps, and every step for a train no fleet command answered yet;
only on topics with a reader) and ``/clock`` every ``clock_every`` steps
(:class:`FleetStatePublisher`).  It keeps what a re-send needs: the message of step k for
an ATO process that matched late, the step's fleet-state rows for the trains whose command
did not come (a state lost with a killed ATO process).  Times are simulated seconds of the
plant (``line.t``); steps are lockstep step indices.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
from rclpy.publisher import Publisher

from metro_atc.core.plant.views import fleet_state_rows
from metro_atc.nodes import conversions as conv
from metro_atc.nodes.wire import cdr, fleet_state


class FleetStatePublisher:
    """What the ATOs answer, published at every step (see the module docstring).

    ``ids``: the train ids; ``line``: the plant (``t`` [s], ``active_mask()``,
    ``states()``); ``fleet_pub``, ``state_pubs`` (in ``ids`` order), ``clock_pub``: the
    ``/line/fleet_state``, ``/<train>/state`` and ``/clock`` publishers; ``state_every``:
    steps between the per-train states of fleet-driven trains; ``clock_every``: steps
    between /clock messages.
    """

    def __init__(self, ids: Sequence[str], line: Any, fleet_pub: Publisher,
                 state_pubs: Sequence[Publisher], clock_pub: Publisher, state_every: int,
                 clock_every: int) -> None:
        """Nothing published yet."""
        n = len(ids)
        self.ids = list(ids)
        self.line = line
        self.fleet_pub = fleet_pub
        self.state_pubs = list(state_pubs)
        self.clock_pub = clock_pub
        self.state_every = int(state_every)
        """Steps between per-train states of fleet-driven trains."""
        self.clock_every = int(clock_every)
        """Steps between /clock messages."""
        self.resends = 0
        """Fleet states published again for trains that did not answer in time."""
        self.active = np.zeros(n, dtype=bool)
        """Active trains of the last step published."""
        self.active_idx = np.zeros(0, dtype=np.intp)
        self.active_idx_k = -1
        """Their indices, and the step they are of."""
        self._echo_mask = np.zeros(n, dtype=bool)
        """Trains whose per-train state was published at step k too (fleet ``echo``)."""
        self._matched = np.zeros(n, dtype=np.int64)
        self._fleet_matched = 0
        self._fleet_msg: bytes | None = None
        """The serialized fleet state of step k (published again to a late ATO process)."""
        self._ids_blocks: dict[bytes, bytes] = {}
        """Serialized train id lists (cdr.string_seq) by the train indices' bytes."""
        self._state_builders: dict[bytes, fleet_state.Builder] = {}
        """FleetState layouts by the train indices' bytes."""
        self._step_rows: tuple[int, np.ndarray, dict[str, np.ndarray]] = (-1, np.zeros(0), {})
        """(k, the active trains, their fleet-state arrays published at step k): a re-send
        (:meth:`publish_again`) takes them again."""

    def publish_clock(self, k: int) -> None:
        """Publish /clock at the plant's time, at step ``k`` (every ``clock_every`` steps)."""
        if k % self.clock_every == 0:
            self.clock_pub.publish(cdr.clock(float(self.line.t)))

    def publish(self, k: int, fleet_driven: np.ndarray) -> np.ndarray:
        """Publish what the ATOs answer at step ``k``: the fleet state, the per-train states.

        ``fleet_driven``: the trains whose ATO answers the fleet state (their per-train
        state every ``state_every`` steps only). Returns the active mask.
        """
        line = self.line
        t = float(line.t)
        active = np.asarray(line.active_mask(), dtype=bool)
        per_train = active if k % self.state_every == 0 else active & ~fleet_driven
        if per_train.any():
            # a topic nobody reads is not published (outside tools that subscribe get it at
            # the declared rate; the fleet state carries every step): no writes, and no
            # per-train command echoes from the ATOs for them
            per_train = self._state_read(per_train)
        idx = np.flatnonzero(active)
        self._echo_mask = per_train
        self.active_idx, self.active_idx_k, self.active = idx, k, active
        # the fleet state's arrays of the active trains only (not every state array of
        # every train: the lockstep's critical path), the same values
        rows = fleet_state_rows(line, idx)
        self._step_rows = (k, idx, rows)
        self._fleet_msg = fleet_state.from_core_rows(self.state_builder(idx), idx.size, rows,
                                                     k, t, per_train[idx])
        self.fleet_pub.publish(self._fleet_msg)
        if per_train.any():
            self.publish_states(k, per_train)
        return active

    def _state_read(self, mask: np.ndarray) -> np.ndarray:
        """``mask`` less the trains whose ``/<train>/state`` has no subscriber.

        Only the trains in ``mask`` are asked (one graph query each, on the step path).
        """
        out = np.zeros_like(mask)
        for i in np.flatnonzero(mask):
            out[i] = self.state_pubs[i].get_subscription_count() > 0
        return out

    def publish_states(self, k: int, trains: np.ndarray) -> None:
        """Publish the step-``k`` states of ``trains`` (due, or again for a late ATO)."""
        t = float(self.line.t)
        for i, m in conv.state_msgs(self.ids, np.flatnonzero(trains), self.line.states(),
                                    k, t):
            self.state_pubs[i].publish(m)

    def new_subscribers(self, active: np.ndarray) -> np.ndarray:
        """Active trains whose state topic matched a new subscriber since the last check."""
        cnt = np.array([p.get_subscription_count() for p in self.state_pubs], dtype=np.int64)
        changed = active & (cnt != self._matched)
        self._matched = cnt
        return changed

    def new_fleet_subscribers(self) -> bool:
        """The fleet state topic matched a new (or lost a) subscriber since the last check."""
        n = self.fleet_pub.get_subscription_count()
        changed = n != self._fleet_matched
        self._fleet_matched = n
        return changed

    def publish_again(self, k: int, cmd_step: np.ndarray,
                      active: np.ndarray | None = None) -> None:
        """Publish the step-``k`` fleet state again.

        Without ``active``: the whole message (an ATO process that matched late). With it:
        the entries of the active trains whose command of step ``k`` has not arrived
        (``cmd_step``: the step of each train's last command; a state lost with a killed ATO
        process, its restarted successor never saw it). A re-sent state is answered with
        the same command (the ATO does not track it twice).
        """
        if active is None:
            if self._fleet_msg is not None:
                self.fleet_pub.publish(self._fleet_msg)
            return
        k_rows, idx, rows = self._step_rows
        missing = np.flatnonzero(active & (cmd_step < k))
        if k_rows != k or missing.size == 0:
            return
        # the entries published at step k (``active`` is step k's active mask)
        at = np.searchsorted(idx, missing)
        if int(at.max()) < idx.size and np.array_equal(idx[at], missing):
            again = {key: a[at] for key, a in rows.items()}
        else:  # not one of them (never in the loop): their states now
            again = fleet_state_rows(self.line, missing)
        self.resends += 1
        self.fleet_pub.publish(fleet_state.from_core_rows(
            self.state_builder(missing), missing.size, again, k, float(self.line.t),
            self._echo_mask[missing]))

    def state_builder(self, idx: np.ndarray) -> fleet_state.Builder:
        """The FleetState layout of the trains ``idx`` (cached per index list)."""
        key = np.asarray(idx, dtype=np.int64).tobytes()
        got = self._state_builders.get(key)
        if got is None:
            if len(self._state_builders) > 256:
                self._state_builders.clear()
            got = self._state_builders[key] = fleet_state.Builder(self.ids_block(idx),
                                                                  len(idx))
        return got

    def ids_block(self, idx: np.ndarray) -> bytes:
        """The train ids of ``idx`` as a serialized string[] (cached per index list)."""
        key = np.asarray(idx, dtype=np.int64).tobytes()
        block = self._ids_blocks.get(key)
        if block is None:
            if len(self._ids_blocks) > 1024:
                self._ids_blocks.clear()
            block = self._ids_blocks[key] = cdr.string_seq([self.ids[i] for i in idx])
        return block
