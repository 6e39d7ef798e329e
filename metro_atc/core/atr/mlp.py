"""Small multilayer perceptron in torch with hand-written backpropagation (Lin 2010a, sec. 3).

The critic and actor of AOC/DHP are MLPs (Lin 2010a: "learning structures constructed by
multilayer perceptrons").  Training updates them once per simulation step, so we avoid the
autograd tape and write the three products we need by hand:

    y = W2 tanh(W1 z + b1) + b2 + L z,

``vjp_input`` gives (dy/dz)^T g (used for dû/dx in the costate equation, Lin 2010a, eq. 30/34)
and ``grad_params`` gives (dy/dtheta)^T g summed over the batch (eq. 44/48).  Both are
checked against autograd and finite differences in ``test/test_atr_gradients.py``.
All parameters live in one flat float64 tensor so that momentum updates are two ops.
"""

from __future__ import annotations

from typing import Dict, Tuple

import numpy as np
import torch

Tensor = torch.Tensor


class MLP:
    """One-hidden-layer tanh MLP with an optional linear skip term (float64, CPU)."""

    def __init__(self, n_in: int, n_hidden: int, n_out: int, seed: int = 0,
                 skip: bool = True, out_gain: float = 0.1) -> None:
        """Initialise Glorot-uniform weights (seeded); the output layer is scaled by out_gain."""
        self.n_in, self.n_hidden, self.n_out, self.skip = n_in, n_hidden, n_out, skip
        sizes = [n_hidden * n_in, n_hidden, n_out * n_hidden, n_out]
        if skip:
            sizes.append(n_out * n_in)
        self._offsets = np.cumsum([0] + sizes)
        self.theta = torch.zeros(int(self._offsets[-1]), dtype=torch.float64)
        g = torch.Generator().manual_seed(int(seed))
        lim1 = float(np.sqrt(6.0 / (n_in + n_hidden)))
        lim2 = float(np.sqrt(6.0 / (n_hidden + n_out))) * out_gain
        w1 = (torch.rand(n_hidden, n_in, generator=g, dtype=torch.float64) * 2 - 1) * lim1
        w2 = (torch.rand(n_out, n_hidden, generator=g, dtype=torch.float64) * 2 - 1) * lim2
        # views into theta (stay valid: theta is only ever updated in place)
        self.w1 = self._view(0, (n_hidden, n_in))
        self.b1 = self._view(1, (n_hidden,))
        self.w2 = self._view(2, (n_out, n_hidden))
        self.b2 = self._view(3, (n_out,))
        self.lin = (self._view(4, (n_out, n_in)) if skip
                    else torch.zeros(n_out, n_in, dtype=torch.float64))
        self.w1.copy_(w1)
        self.w2.copy_(w2)

    def _view(self, idx: int, shape: Tuple[int, ...]) -> Tensor:
        a, b = int(self._offsets[idx]), int(self._offsets[idx + 1])
        return self.theta[a:b].view(*shape)

    def forward(self, z: Tensor) -> Tuple[Tensor, Tuple[Tensor, Tensor]]:
        """Return (y, cache) for inputs z of shape (B, n_in); y has shape (B, n_out)."""
        a = torch.tanh(torch.addmm(self.b1, z, self.w1.T))
        y = torch.addmm(self.b2, a, self.w2.T)
        if self.skip:
            y = y + z @ self.lin.T
        return y, (z, a)

    def __call__(self, z: Tensor) -> Tensor:
        """Forward pass without cache."""
        return self.forward(z)[0]

    def vjp_input(self, cache: Tuple[Tensor, Tensor], gy: Tensor) -> Tensor:
        """(dy/dz)^T gy per sample, shape (B, n_in)."""
        _, a = cache
        gz = ((gy @ self.w2) * (1.0 - a * a)) @ self.w1
        if self.skip:
            gz = gz + gy @ self.lin
        return gz

    def grad_params(self, cache: Tuple[Tensor, Tensor], gy: Tensor) -> Tensor:
        """Sum over the batch of (dy/dtheta)^T gy, as a flat tensor like theta."""
        z, a = cache
        ga = (gy @ self.w2) * (1.0 - a * a)
        parts = [(ga.T @ z).reshape(-1), ga.sum(0), (gy.T @ a).reshape(-1), gy.sum(0)]
        if self.skip:
            parts.append((gy.T @ z).reshape(-1))
        return torch.cat(parts)

    def state(self) -> Dict[str, object]:
        """Serialisable description (sizes + parameters)."""
        return {"n_in": self.n_in, "n_hidden": self.n_hidden, "n_out": self.n_out,
                "skip": self.skip, "theta": self.theta.clone()}

    @classmethod
    def from_state(cls, state: Dict[str, object]) -> "MLP":
        """Rebuild an MLP from :meth:`state` output."""
        net = cls(int(state["n_in"]), int(state["n_hidden"]),  # type: ignore[call-overload]
                  int(state["n_out"]), skip=bool(state["skip"]))  # type: ignore[call-overload]
        theta = state["theta"]
        if not isinstance(theta, torch.Tensor) or theta.shape != net.theta.shape:
            raise ValueError("MLP state has parameters of the wrong shape")
        net.theta.copy_(theta.to(torch.float64))
        return net
