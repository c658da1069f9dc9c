"""Compiled inference of a stacked LSTM with a linear output (no torch needed at run time).

PyTorch's LSTM (gates in the order input, forget, cell, output; Lipton et al.,
the third paper's Eq. 11-16) evaluated sample by sample in numba, in single
precision like the training (tanh and the sigmoid by a branch-free rational
approximation, |error| < 3e-7, with float32 constants and numpy's error
model: numba's default zero-division check on ``/`` otherwise stops the gate
loop from vectorising, which cost a factor 1.7), with the
hidden and cell states (and the last inputs of a multi-tap linear skip) carried
in :class:`LSTMState`: a trace processed at once or chunk by chunk gives the
same numbers to the bit.  A state may be primed on the first input held
constant (:class:`LSTMState` ``warmup``) instead of starting from zero.
Optional dropout masks
between layers give Monte-Carlo-dropout samples for prediction intervals.

Layout for the kernel: per layer, the input and recurrent weights stacked and
transposed, ``(layers, max_in + H, 4H)`` with zero rows up to a multiple of
four, so that each step sweeps the gate rows once per four inputs; the skip's
taps flattened oldest first, so that its output is one dot product of the
step's input window (a chunk's rows follow the carried ones in one array, so
a trace at once and chunk by chunk sum alike).  A sweep per input (the gates
loaded and stored 135 times a step) and the skip summed lag by lag with a
branch per lag had made the kernel 1.4x slower.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

__all__ = ["LSTMWeights", "LSTMState", "run_lstm", "skip_to_torch"]


@dataclass(frozen=True)
class LSTMWeights:
    """Weights of a stacked LSTM and its linear head, packed for the kernel.

    The network maps scaled inputs to a scaled output, so every weight is
    dimensionless.

    Attributes
    ----------
    w_ih : ndarray, shape (layers, 4H, max_in)
        Input weights [-] (zero-padded past each layer's input width).
    w_hh : ndarray, shape (layers, 4H, H)
        Recurrent weights [-].
    bias : ndarray, shape (layers, 4H)
        ``b_ih + b_hh`` [-].
    in_dims : ndarray of int, shape (layers,)
        Input width of each layer.
    head_w : ndarray, shape (H,)
        Output weights [-].
    head_b : float
        Output bias [-].
    skip_w : ndarray, shape (inputs,) or (inputs, taps), optional
        Linear skip from the inputs straight to the output [-]: a causal FIR filter,
        column ``k`` weighting the inputs ``k`` samples back (``skip.weight``);
        None: no skip (the paper's network).
    dropout : float
        Dropout probability between layers [-] (used only when sampling).
    """

    w_ih: np.ndarray
    w_hh: np.ndarray
    bias: np.ndarray
    in_dims: np.ndarray
    head_w: np.ndarray
    head_b: float
    dropout: float = 0.0
    skip_w: np.ndarray | None = None

    def __post_init__(self) -> None:
        layers, g4, max_in = self.w_ih.shape
        hid = g4 // 4
        packed = np.zeros((layers, -(-(max_in + hid) // 4) * 4, g4), dtype=np.float32)   # rows: a multiple of 4
        for k in range(layers):
            n_in = int(self.in_dims[k])
            packed[k, :n_in] = self.w_ih[k, :, :n_in].T
            packed[k, n_in:n_in + hid] = self.w_hh[k].T
        scale = np.full(g4, 0.5, dtype=np.float32)      # sigmoid(x) = (1 + tanh(x / 2)) / 2; the cell gate is tanh
        scale[2 * hid:3 * hid] = 1.0
        object.__setattr__(self, "packed", packed)
        object.__setattr__(self, "packed_bias", np.ascontiguousarray(self.bias, dtype=np.float32))
        object.__setattr__(self, "gate_scale", scale)
        object.__setattr__(self, "packed_head", np.ascontiguousarray(self.head_w, dtype=np.float32))
        skip = np.zeros((int(self.in_dims[0]), 1), dtype=np.float32)
        if self.skip_w is not None:
            given = np.asarray(self.skip_w, dtype=np.float32)
            skip = np.ascontiguousarray(given.reshape(given.shape[0], -1))
        object.__setattr__(self, "packed_skip", skip)
        # the taps as one window of input rows, oldest first: row-major (taps, inputs), the last row the current one
        object.__setattr__(self, "packed_fir", np.ascontiguousarray(skip[:, ::-1].T).ravel())

    @property
    def taps(self) -> int:
        """Samples the linear skip looks back over (1: the current one only)."""
        return self.packed_skip.shape[1]

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
            Mapping of names to arrays (tensors are converted with ``numpy()``);
            ``skip.weight`` (a linear skip from the inputs) is optional: a
            ``Linear`` weight ``(1, inputs)`` or a causal ``Conv1d`` weight
            ``(1, inputs, taps)`` (last tap = current sample).
        layers : int
            Number of LSTM layers.
        dropout : float
            Dropout probability between layers [-].
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
                   float(dropout), _skip_from_torch(arr("skip.weight")) if "skip.weight" in state else None)


def _skip_from_torch(w: np.ndarray) -> np.ndarray:
    """(inputs, taps) by lag from a Linear (1, inputs) or causal Conv1d (1, inputs, taps) weight."""
    return np.ascontiguousarray(w[0, :, ::-1] if w.ndim == 3 else w.reshape(-1, 1))


def skip_to_torch(skip_w: np.ndarray) -> np.ndarray:
    """The causal ``Conv1d`` weight ``(1, inputs, taps)`` of a skip given by lag (inverse of loading).

    Parameters
    ----------
    skip_w : ndarray, shape (inputs,) or (inputs, taps)
        Skip weights by lag [-] (column ``k``: ``k`` samples back), as
        :attr:`LSTMWeights.skip_w`.

    Returns
    -------
    ndarray, shape (1, inputs, taps)
    """
    # a copy: ascontiguousarray keeps the negative stride of a one-tap filter, which torch.from_numpy refuses
    return np.asarray(skip_w, dtype=np.float64).reshape(len(skip_w), -1)[None, :, ::-1].copy()


class LSTMState:
    """Hidden and cell states of one network (constant size, single precision).

    Parameters
    ----------
    weights : LSTMWeights
        The network.
    warmup : int, optional
        Priming steps: before the first row it is given, :func:`run_lstm`
        runs the network this many steps on that row held constant (outputs
        discarded), so that the states (and the skip's past inputs) start where
        a machine resting in that state would hold them rather than at zero.
        0 (default): a zero state, as PyTorch starts.
    """

    def __init__(self, weights: LSTMWeights, warmup: int = 0) -> None:
        self.h = np.zeros((weights.layers, weights.hidden), dtype=np.float32)
        self.c = np.zeros((weights.layers, weights.hidden), dtype=np.float32)
        #: the last ``taps - 1`` input rows, oldest first (zeros at the start, like the causal padding in training)
        self.tail = np.zeros((weights.taps - 1, int(weights.in_dims[0])), dtype=np.float32)
        #: priming steps still to run on the first row (0 once primed)
        self.warmup = int(warmup)


def run_lstm(weights: LSTMWeights, state: LSTMState, x: np.ndarray, *, seed: int | None = None) -> np.ndarray:
    """Run the network over the rows of ``x`` (scaled inputs) and return one output per row.

    A state with priming steps pending (``LSTMState(weights, warmup=n)``) is
    first run ``n`` steps on the first row of the first non-empty call, so a
    trace processed at once or chunk by chunk is primed alike.

    Parameters
    ----------
    weights : LSTMWeights
        The network.
    state : LSTMState
        Carried state (updated in place).
    x : ndarray, shape (n, inputs)
        Scaled inputs [-].
    seed : int, optional
        With a seed, dropout is applied between layers (Monte-Carlo dropout);
        without, the network runs deterministically (evaluation mode).

    Returns
    -------
    ndarray, shape (n,)
        Network output (float64).

    Raises
    ------
    ValueError
        If ``x`` is not one row of the network's inputs per sample.
    """
    x = np.ascontiguousarray(x, dtype=np.float32)
    if x.ndim != 2 or x.shape[1] != int(weights.in_dims[0]):
        raise ValueError(f"the network takes {int(weights.in_dims[0])} inputs per row, got an array of shape {x.shape}")
    if state.warmup > 0 and x.shape[0] > 0:
        _run(weights, state, np.repeat(x[:1], state.warmup, axis=0), 0.0, -1)   # prime: the first row held
        state.warmup = 0
    p = weights.dropout if seed is not None else 0.0
    return _run(weights, state, x, p, -1 if seed is None else int(seed)).astype(np.float64)


def _run(weights: LSTMWeights, state: LSTMState, x: np.ndarray, p: float, seed: int) -> np.ndarray:
    """One kernel call over the rows of ``x`` (float32, contiguous), carrying ``state``; float32 outputs."""
    keep = state.tail.shape[0]
    rows = np.concatenate([state.tail, x]) if keep else x        # the skip's window: carried rows, then these
    out = np.empty(x.shape[0], dtype=np.float32)
    _lstm(weights.packed, weights.packed_bias, weights.gate_scale, weights.in_dims, weights.packed_head,
          np.float32(weights.head_b), weights.packed_fir, rows, state.h, state.c, out, np.float32(p), seed)
    if keep:
        state.tail = rows[-keep:].copy()
    return out


_F = np.float32
_CLIP = _F(7.90531110763549805)
_P0, _P1, _P2, _P3, _P4, _P5, _P6 = (_F(c) for c in (
    -2.76076847742355e-16, 2.00018790482477e-13, -8.60467152213735e-11, 5.12229709037114e-08,
    1.48572235717979e-05, 6.37261928875436e-04, 4.89352455891786e-03))
_Q0, _Q1, _Q2, _Q3 = (_F(c) for c in (1.19825839466702e-06, 1.18534705686654e-04, 2.26843463243900e-03,
                                      4.89352518554385e-03))


@njit(cache=True, fastmath=True, inline="always", error_model="numpy")
def _tanh(x):
    """tanh by a [13/6] rational approximation on [-7.905, 7.905], saturated beyond.

    Branch-free and in single precision throughout (float32 constants; numpy's
    error model, so no zero-division check) so that loops over it vectorise.
    """
    x = x if x < _CLIP else _CLIP
    x = x if x > -_CLIP else -_CLIP
    x2 = x * x
    p = x2 * _P0 + _P1
    p = x2 * p + _P2
    p = x2 * p + _P3
    p = x2 * p + _P4
    p = x2 * p + _P5
    p = x2 * p + _P6
    q = x2 * _Q0 + _Q1
    q = x2 * q + _Q2
    q = x2 * q + _Q3
    return x * p / q


@njit(cache=True, fastmath=True, nogil=True, error_model="numpy")
def _lstm(w, bias, scale, in_dims, head_w, head_b, fir, rows, h, c, out, p, seed):
    """``out[t]`` for the last ``len(out)`` of ``rows``; the ``taps - 1`` rows before them fill the skip's window."""
    layers, _, g4 = w.shape
    hid = g4 // 4
    span = fir.shape[0]
    first = span // in_dims[0] - 1                   # rows before the first output: taps - 1
    flat = rows.reshape(-1)
    z = np.zeros(w.shape[1], dtype=np.float32)
    gates = np.empty(g4, dtype=np.float32)
    if seed >= 0:
        np.random.seed(seed)
    keep = 1.0 - p
    for t in range(out.shape[0]):
        for k in range(layers):
            n_in = in_dims[k]
            if k == 0:
                for j in range(n_in):
                    z[j] = rows[first + t, j]
            else:
                for j in range(hid):
                    v = h[k - 1, j]
                    if p > 0.0:
                        v = v / keep if np.random.random() < keep else 0.0
                    z[j] = v
            for j in range(hid):
                z[n_in + j] = h[k, j]
            m = n_in + hid
            for j in range(m, (m + 3) // 4 * 4):     # the padding rows' inputs (their weights are zero)
                z[j] = 0.0
            for r in range(g4):
                gates[r] = bias[k, r]
            for j in range(0, m, 4):                  # four inputs per sweep over the gates
                z0, z1, z2, z3 = z[j], z[j + 1], z[j + 2], z[j + 3]
                for r in range(g4):
                    gates[r] += w[k, j, r] * z0 + w[k, j + 1, r] * z1 + w[k, j + 2, r] * z2 + w[k, j + 3, r] * z3
            for r in range(g4):
                gates[r] = _tanh(scale[r] * gates[r])
            for j in range(hid):
                cc = (0.5 + 0.5 * gates[hid + j]) * c[k, j] + (0.5 + 0.5 * gates[j]) * gates[2 * hid + j]
                c[k, j] = cc
                h[k, j] = (0.5 + 0.5 * gates[3 * hid + j]) * _tanh(cc)
        y = head_b
        for j in range(hid):
            y += head_w[j] * h[layers - 1, j]
        window = flat[t * in_dims[0]:t * in_dims[0] + span]
        s = np.float32(0.0)
        for j in range(span):
            s += fir[j] * window[j]
        out[t] = y + s
