"""Compiled inference of a stacked LSTM with a linear output (no torch needed at run time).

PyTorch's LSTM (gates in the order input, forget, cell, output; Lipton et al.,
the third paper's Eq. 11-16) evaluated sample by sample in numba (tanh and the
sigmoid by a rational approximation, |error| < 2e-7), with the
hidden and cell states carried in :class:`LSTMState`: a trace processed at once
or chunk by chunk gives the same numbers to the bit.  Optional dropout masks
between layers give Monte-Carlo-dropout samples for prediction intervals.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

__all__ = ["LSTMWeights", "LSTMState", "run_lstm"]


@dataclass(frozen=True)
class LSTMWeights:
    """Weights of a stacked LSTM and its linear head, packed for the kernel.

    Attributes
    ----------
    w_ih : ndarray, shape (layers, 4H, max_in)
        Input weights (zero-padded past each layer's input width).
    w_hh : ndarray, shape (layers, 4H, H)
        Recurrent weights.
    bias : ndarray, shape (layers, 4H)
        ``b_ih + b_hh``.
    in_dims : ndarray of int, shape (layers,)
        Input width of each layer.
    head_w : ndarray, shape (H,)
        Output weights.
    head_b : float
        Output bias.
    dropout : float
        Dropout probability between layers (used only when sampling).
    """

    w_ih: np.ndarray
    w_hh: np.ndarray
    bias: np.ndarray
    in_dims: np.ndarray
    head_w: np.ndarray
    head_b: float
    dropout: float = 0.0

    @property
    def layers(self) -> int:
        """Number of stacked layers."""
        return self.w_hh.shape[0]

    @property
    def hidden(self) -> int:
        """Cells per layer."""
        return self.w_hh.shape[2]

    @classmethod
    def from_state_dict(cls, state: dict, layers: int, dropout: float = 0.0) -> "LSTMWeights":
        """Pack a PyTorch ``state_dict`` (``lstm.weight_ih_l{k}``..., ``head.weight``, ``head.bias``).

        Parameters
        ----------
        state : dict
            Mapping of names to arrays (tensors are converted with ``numpy()``).
        layers : int
            Number of LSTM layers.
        dropout : float
            Dropout probability between layers.
        """
        def arr(name):
            v = state[name]
            return np.asarray(v.detach().cpu().numpy() if hasattr(v, "detach") else v, dtype=np.float64)

        w_ih = [arr(f"lstm.weight_ih_l{k}") for k in range(layers)]
        w_hh = [arr(f"lstm.weight_hh_l{k}") for k in range(layers)]
        bias = [arr(f"lstm.bias_ih_l{k}") + arr(f"lstm.bias_hh_l{k}") for k in range(layers)]
        max_in = max(w.shape[1] for w in w_ih)
        packed_ih = np.zeros((layers, w_ih[0].shape[0], max_in))
        for k, w in enumerate(w_ih):
            packed_ih[k, :, : w.shape[1]] = w
        return cls(np.ascontiguousarray(packed_ih), np.ascontiguousarray(np.stack(w_hh)),
                   np.ascontiguousarray(np.stack(bias)), np.array([w.shape[1] for w in w_ih], dtype=np.int64),
                   np.ascontiguousarray(arr("head.weight").ravel()), float(arr("head.bias").ravel()[0]),
                   float(dropout))


class LSTMState:
    """Hidden and cell states of one network (constant size).

    Parameters
    ----------
    weights : LSTMWeights
        The network.
    """

    def __init__(self, weights: LSTMWeights) -> None:
        self.h = np.zeros((weights.layers, weights.hidden))
        self.c = np.zeros((weights.layers, weights.hidden))


def run_lstm(weights: LSTMWeights, state: LSTMState, x: np.ndarray, *, seed: int | None = None) -> np.ndarray:
    """Run the network over the rows of ``x`` (scaled inputs) and return one output per row.

    Parameters
    ----------
    weights : LSTMWeights
        The network.
    state : LSTMState
        Carried state (updated in place).
    x : ndarray, shape (n, inputs)
        Scaled inputs.
    seed : int, optional
        With a seed, dropout is applied between layers (Monte-Carlo dropout);
        without, the network runs deterministically (evaluation mode).
    """
    x = np.ascontiguousarray(x, dtype=np.float64)
    out = np.empty(x.shape[0])
    p = weights.dropout if seed is not None else 0.0
    _lstm(weights.w_ih, weights.w_hh, weights.bias, weights.in_dims, weights.head_w, weights.head_b,
          state.h, state.c, x, out, p, -1 if seed is None else int(seed))
    return out


@njit(cache=True, fastmath=True, inline="always")
def _tanh(x):
    """tanh: Lambert's continued fraction (7 terms) for |x| < 2.5, the exponential form beyond."""
    if x > 2.5 or x < -2.5:
        return 1.0 - 2.0 / (np.exp(2.0 * x) + 1.0)
    x2 = x * x
    return x * (135135.0 + x2 * (17325.0 + x2 * (378.0 + x2))) / (135135.0 + x2 * (62370.0 + x2 * (3150.0 + x2 * 28.0)))


@njit(cache=True, fastmath=True, nogil=True)
def _lstm(w_ih, w_hh, bias, in_dims, head_w, head_b, h, c, x, out, p, seed):
    layers, g4, _ = w_ih.shape
    hid = g4 // 4
    inp = np.empty(max(w_ih.shape[2], hid))
    gates = np.empty(g4)
    if seed >= 0:
        np.random.seed(seed)
    keep = 1.0 - p
    for t in range(x.shape[0]):
        n_in = in_dims[0]
        for j in range(n_in):
            inp[j] = x[t, j]
        for k in range(layers):
            n_in = in_dims[k]
            for r in range(g4):
                acc = bias[k, r]
                for j in range(n_in):
                    acc += w_ih[k, r, j] * inp[j]
                for j in range(hid):
                    acc += w_hh[k, r, j] * h[k, j]
                gates[r] = acc
            for j in range(hid):
                i_g = 0.5 + 0.5 * _tanh(0.5 * gates[j])
                f_g = 0.5 + 0.5 * _tanh(0.5 * gates[hid + j])
                g_g = _tanh(gates[2 * hid + j])
                o_g = 0.5 + 0.5 * _tanh(0.5 * gates[3 * hid + j])
                c[k, j] = f_g * c[k, j] + i_g * g_g
                h[k, j] = o_g * _tanh(c[k, j])
            for j in range(hid):
                v = h[k, j]
                if p > 0.0 and k < layers - 1:
                    v = v / keep if np.random.random() < keep else 0.0
                inp[j] = v
        y = head_b
        for j in range(hid):
            y += head_w[j] * inp[j]
        out[t] = y
