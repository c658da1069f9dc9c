"""Compiled inference of a stacked LSTM with a linear output (no torch needed at run time).

PyTorch's LSTM (gates in the order input, forget, cell, output; Lipton et al.,
the third paper's Eq. 11-16) evaluated in numba, in single precision like the
training, with the hidden and cell states (and the last inputs of a multi-tap
linear skip) carried in :class:`LSTMState`: a trace processed at once or chunk
by chunk gives the same numbers to the bit.  A state may be primed on the
first input held constant (:class:`LSTMState` ``warmup``) instead of starting
from zero.  Optional dropout masks between layers give Monte-Carlo-dropout
samples for prediction intervals.

The loops are compiled per network shape, with the hidden size and the input
width as compile-time constants (closed over by the compiled function; numba
keys its on-disk cache on them, so each shape compiles once per machine, in
about 5 s): the compiler then knows every trip count and unrolls the gate
loops into vector registers.  The network runs layer by layer over blocks of
``BLOCK`` samples: first the input part of a layer's gates for the whole
block (no dependence between samples), then the recurrence, which adds only
the hidden state's part.  A sample's arithmetic is the same in any block, so
chunking cannot change a bit.  Both together made the kernel 2x faster than
one loop over samples with the sizes read at run time (``bench learn``'s
3 x 20-cell networks: 110 ms against 218 ms for its held-out runs, serial).

PyTorch's gate order; tanh and the sigmoid by a branch-free rational
approximation (|error| < 3e-7) with float32 constants and numpy's error model
(numba's zero-division check on ``/`` stops the gate loops from vectorising).

Layout for the kernel: per layer, the input and the recurrent weights
transposed, ``(layers, inputs, 4H)`` and ``(layers, H, 4H)``, with zero rows
up to a multiple of four so that each sweep over the gate rows takes four
inputs; the skip's taps flattened oldest first, so that its output is one
dot product of the step's input window (a chunk's rows follow the carried
ones in one array, so a trace at once and chunk by chunk sum alike).
"""

from __future__ import annotations

import threading
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
        packed_ih = np.zeros((layers, -(-max_in // 4) * 4, g4), dtype=np.float32)    # rows: a multiple of 4
        packed_hh = np.zeros((layers, -(-hid // 4) * 4, g4), dtype=np.float32)
        for k in range(layers):
            n_in = int(self.in_dims[k])
            packed_ih[k, :n_in] = self.w_ih[k, :, :n_in].T
            packed_hh[k, :hid] = self.w_hh[k].T
        scale = np.full(g4, 0.5, dtype=np.float32)      # sigmoid(x) = (1 + tanh(x / 2)) / 2; the cell gate is tanh
        scale[2 * hid:3 * hid] = 1.0
        object.__setattr__(self, "packed_ih", packed_ih)
        object.__setattr__(self, "packed_hh", packed_hh)
        object.__setattr__(self, "gate_scale", scale)
        object.__setattr__(self, "packed_bias", np.ascontiguousarray(self.bias, dtype=np.float32))
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
    _kernel_for(weights.hidden, int(weights.in_dims[0]))(
        weights.packed_ih, weights.packed_hh, weights.packed_bias, weights.gate_scale, weights.packed_head,
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
_HALF = _F(0.5)


@njit(cache=True, fastmath=True, inline="always", error_model="numpy")
def _tanh(x):
    """tanh by a [13/6] rational approximation on [-7.905, 7.905], saturated beyond.

    Branch-free and in single precision throughout so that loops over it vectorise.
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


#: Samples per block: a block's gates (BLOCK x 4H floats) stay in the first cache levels.
BLOCK = 256

_KERNELS: dict = {}
_KERNELS_LOCK = threading.Lock()


def _kernel_for(hidden: int, inputs: int):
    """The compiled loops for networks of ``hidden`` cells and ``inputs`` first-layer inputs (made once)."""
    key = (int(hidden), int(inputs))
    if key not in _KERNELS:
        with _KERNELS_LOCK:                     # the three networks of a model ask from the pool's threads at once
            if key not in _KERNELS:
                _KERNELS[key] = _make_kernel(*key)
    return _KERNELS[key]


def _make_kernel(HID: int, NIN: int):
    """Compile the LSTM's loops with the sizes as constants (numba keys its on-disk cache on them)."""
    G4 = 4 * HID                        # gate rows per layer
    HID4 = (HID + 3) // 4 * 4           # hidden inputs padded to whole sweeps of four
    NIN4 = (NIN + 3) // 4 * 4           # first-layer inputs padded likewise
    ZW = max(NIN4, HID4)

    @njit(cache=True, fastmath=True, nogil=True, error_model="numpy")
    def run_steps(wih, whh, bias, scale, head_w, head_b, fir, rows, h, c, out, p, seed):
        """``out[t]`` for the last ``len(out)`` of ``rows`` (the ``taps - 1`` rows before them: the skip's window)."""
        layers = wih.shape[0]
        span = fir.shape[0]
        first = span // NIN - 1                      # rows before the first output: taps - 1
        flat = rows.reshape(-1)
        n = out.shape[0]
        gates = np.empty((BLOCK, G4), dtype=np.float32)
        hs = np.empty((BLOCK, HID), dtype=np.float32)
        z = np.zeros(ZW, dtype=np.float32)
        act = np.empty(G4, dtype=np.float32)
        if seed >= 0:
            np.random.seed(seed)
        keep = 1.0 - p
        for t0 in range(0, n, BLOCK):
            m = min(BLOCK, n - t0)
            for k in range(layers):
                # the input part of the block's gates: no dependence between samples, the loops stream (two
                # loops, the first layer's and the others', so that each sweeps a constant width: one loop
                # with the width chosen per layer measured 5-10 % slower)
                if k == 0:
                    for i in range(m):
                        for j in range(NIN):
                            z[j] = rows[first + t0 + i, j]
                        for j in range(NIN, NIN4):
                            z[j] = 0.0
                        for r in range(G4):
                            gates[i, r] = bias[k, r]
                        for j in range(0, NIN4, 4):
                            z0, z1, z2, z3 = z[j], z[j + 1], z[j + 2], z[j + 3]
                            for r in range(G4):
                                gates[i, r] += (wih[k, j, r] * z0 + wih[k, j + 1, r] * z1 + wih[k, j + 2, r] * z2
                                                + wih[k, j + 3, r] * z3)
                else:
                    if p > 0.0:                      # Monte-Carlo dropout on the layer below's output
                        for i in range(m):
                            for j in range(HID):
                                hs[i, j] = hs[i, j] / keep if np.random.random() < keep else 0.0
                    for i in range(m):
                        for j in range(HID):
                            z[j] = hs[i, j]
                        for j in range(HID, HID4):
                            z[j] = 0.0
                        for r in range(G4):
                            gates[i, r] = bias[k, r]
                        for j in range(0, HID4, 4):
                            z0, z1, z2, z3 = z[j], z[j + 1], z[j + 2], z[j + 3]
                            for r in range(G4):
                                gates[i, r] += (wih[k, j, r] * z0 + wih[k, j + 1, r] * z1 + wih[k, j + 2, r] * z2
                                                + wih[k, j + 3, r] * z3)
                # the recurrence adds the hidden state's part, sample after sample
                for j in range(HID, HID4):
                    z[j] = 0.0
                for i in range(m):
                    for j in range(HID):
                        z[j] = h[k, j]
                    for r in range(G4):
                        act[r] = gates[i, r]
                    for j in range(0, HID4, 4):
                        z0, z1, z2, z3 = z[j], z[j + 1], z[j + 2], z[j + 3]
                        for r in range(G4):
                            act[r] += (whh[k, j, r] * z0 + whh[k, j + 1, r] * z1 + whh[k, j + 2, r] * z2
                                       + whh[k, j + 3, r] * z3)
                    for r in range(G4):
                        act[r] = _tanh(scale[r] * act[r])
                    for j in range(HID):
                        cc = (_HALF + _HALF * act[HID + j]) * c[k, j] + (_HALF + _HALF * act[j]) * act[2 * HID + j]
                        c[k, j] = cc
                        hh = (_HALF + _HALF * act[3 * HID + j]) * _tanh(cc)
                        h[k, j] = hh
                        hs[i, j] = hh
            for i in range(m):
                t = t0 + i
                y = head_b
                for j in range(HID):
                    y += head_w[j] * hs[i, j]
                window = flat[t * NIN:t * NIN + span]
                s = np.float32(0.0)
                for j in range(span):
                    s += fir[j] * window[j]
                out[t] = y + s

    return run_steps
