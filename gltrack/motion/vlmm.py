"""Variable length Markov model (VLMM) over discrete symbols (cluster labels).

Learning follows Ron, Singer & Tishby ("The power of amnesia", Machine Learning 25, 1996) as
used by Galata et al. and Caillette et al. (2008, section 4.2): a prediction suffix tree (PST)
is grown from every context (the ``l <= max_memory`` most recent symbols) seen at least
``min_count`` times. A context ``s' = a s`` is *significant* when its weighted Kullback-Leibler
gain over its suffix ``s``

    dH(s') = P(s') * sum_b P(b | s') log(P(b | s') / P(b | s))      (nats)

exceeds ``epsilon``. Every context is examined whether or not its suffix was significant, so
dependencies that only appear at depth 2 (e.g. x_t = x_{t-1} xor x_{t-2}) are still found.
The tree is the significant contexts plus all their suffixes; each node predicts with its
smoothed empirical distribution ``gamma(s, b) = (1 - K g) P(b | s) + g``.

The tree is then turned into a probabilistic finite state automaton (PFSA): states are the
tree nodes closed under taking substrings (added nodes predict like their longest learnt
suffix, so predictions are unchanged). With that closure, the next state
``tau(q, b) = longest suffix of q b that is a state`` always equals the longest suffix of the
*whole* history, so prediction is a table look-up.

Symbol strings are tuples ordered oldest to newest; the last element is the current symbol.
"""
from __future__ import annotations

import logging

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

log = logging.getLogger(__name__)


def _check_sequences(sequences, n_symbols: int) -> list[np.ndarray]:
    if isinstance(sequences, np.ndarray) and sequences.ndim == 1:
        sequences = [sequences]
    out = []
    for i, s in enumerate(sequences):
        a = np.asarray(s)
        if a.ndim != 1 or not (a.size == 0 or np.issubdtype(a.dtype, np.integer)):
            raise ValueError(f"sequence {i} must be a 1-D integer array, got shape {a.shape} "
                             f"dtype {a.dtype}")
        a = a.astype(np.int64)
        if a.size and (a.min() < 0 or a.max() >= n_symbols):
            raise ValueError(f"sequence {i} has symbols outside [0, {n_symbols})")
        out.append(a)
    return out


def count_contexts(sequences: list[np.ndarray], n_symbols: int,
                   max_memory: int) -> dict[tuple, np.ndarray]:
    """Next-symbol counts of every context of length 0..max_memory.

    Returns
    -------
    dict mapping a context tuple (oldest first) to its (n_symbols,) int64 counts.
    """
    counts: dict[tuple, np.ndarray] = {}
    for length in range(max_memory + 1):
        windows = [sliding_window_view(s, length + 1) for s in sequences if s.size > length]
        if not windows:
            break
        w = np.concatenate(windows, axis=0)
        ctx, nxt = w[:, :length], w[:, length]
        if length == 0:
            counts[()] = np.bincount(nxt, minlength=n_symbols).astype(np.int64)
            continue
        uniq, inv = np.unique(ctx, axis=0, return_inverse=True)
        table = np.zeros((len(uniq), n_symbols), dtype=np.int64)
        np.add.at(table, (inv.ravel(), nxt), 1)
        for row, c in zip(uniq, table):
            counts[tuple(int(v) for v in row)] = c
    return counts


class Vlmm:
    """A VLMM as a PFSA (see module docstring). Build with :meth:`fit`.

    Attributes
    ----------
    n_symbols : int, alphabet size K.
    states : list of tuple of int, (Q,), state strings (oldest symbol first); ``states[0] == ()``.
    next_dist : (Q, K) float64, ``gamma(q, b)``: probability of symbol b after state q.
    trans : (Q, K) int64, ``tau(q, b)``: the state reached from q on symbol b.
    learnt : (Q,) bool, True for nodes of the learnt suffix tree (False: added by the closure).
    last_symbol : (Q,) int64, the current symbol of each state (-1 for the empty state).
    max_memory, epsilon, min_count, gamma : the learning parameters.
    """

    def __init__(self, states, next_dist, n_symbols: int, learnt=None, max_memory: int = 10,
                 epsilon: float = 1e-3, min_count: int = 3, gamma: float = 1e-3):
        self.n_symbols = int(n_symbols)
        self.states = [tuple(int(v) for v in s) for s in states]
        self.next_dist = np.asarray(next_dist, dtype=np.float64)
        q = len(self.states)
        self.learnt = (np.ones(q, dtype=bool) if learnt is None
                       else np.asarray(learnt, dtype=bool).reshape(-1))
        self.max_memory, self.epsilon = int(max_memory), float(epsilon)
        self.min_count, self.gamma = int(min_count), float(gamma)
        self._validate()
        self.index = {s: i for i, s in enumerate(self.states)}
        self.last_symbol = np.array([s[-1] if s else -1 for s in self.states], dtype=np.int64)
        self.trans = np.array([[self._longest_suffix(s + (b,)) for b in range(self.n_symbols)]
                               for s in self.states], dtype=np.int64).reshape(q, self.n_symbols)
        self._cdf = np.cumsum(self.next_dist, axis=1)

    def _validate(self) -> None:
        q, k = len(self.states), self.n_symbols
        if k < 1:
            raise ValueError(f"n_symbols must be >= 1, got {k}")
        if q < 1 or self.states[0] != ():
            raise ValueError("states must start with the empty state ()")
        if len(set(self.states)) != q:
            raise ValueError("states must be unique")
        st = set(self.states)
        for s in self.states:
            if len(s) > self.max_memory:
                raise ValueError(f"state {s} is longer than max_memory={self.max_memory}")
            if any(v < 0 or v >= k for v in s):
                raise ValueError(f"state {s} has symbols outside [0, {k})")
            if s and (s[1:] not in st or s[:-1] not in st):
                raise ValueError(f"states are not closed under suffixes/prefixes at {s}")
        if self.next_dist.shape != (q, k):
            raise ValueError(f"next_dist must have shape ({q}, {k}), got {self.next_dist.shape}")
        if (not np.all(np.isfinite(self.next_dist)) or np.any(self.next_dist < 0)
                or not np.allclose(self.next_dist.sum(axis=1), 1.0, atol=1e-6)):
            raise ValueError("next_dist rows must be finite, non-negative and sum to 1")
        if self.learnt.shape != (q,):
            raise ValueError(f"learnt must have shape ({q},), got {self.learnt.shape}")

    def _longest_suffix(self, s: tuple) -> int:
        for start in range(max(0, len(s) - self.max_memory), len(s) + 1):
            i = self.index.get(s[start:])
            if i is not None:
                return i
        return 0

    # ------------------------------------------------------------------ learning
    @classmethod
    def fit(cls, sequences, n_symbols: int, max_memory: int = 10, epsilon: float = 1e-3,
            min_count: int = 3, gamma: float = 1e-3) -> "Vlmm":
        """Learn a VLMM from label sequences.

        Parameters
        ----------
        sequences : list of 1-D int arrays (or one array), symbols in ``[0, n_symbols)``.
        n_symbols : int, alphabet size K.
        max_memory : int >= 0, longest context (memory length) considered.
        epsilon : float >= 0, threshold on the weighted KL gain (nats) for adding a context;
            larger values give fewer states.
        min_count : int >= 1, contexts seen fewer times are not considered.
        gamma : float, smoothing probability added to every symbol; needs ``K * gamma < 1``.

        Returns
        -------
        Vlmm
        """
        if not 0 <= gamma or not n_symbols * gamma < 1:
            raise ValueError(f"gamma must satisfy 0 <= gamma < 1/n_symbols, got {gamma}")
        if max_memory < 0 or min_count < 1 or epsilon < 0:
            raise ValueError("need max_memory >= 0, min_count >= 1 and epsilon >= 0")
        seqs = _check_sequences(sequences, n_symbols)
        total = sum(s.size for s in seqs)
        if total == 0:
            raise ValueError("no symbols to learn from")
        counts = count_contexts(seqs, n_symbols, max_memory)

        significant = {()}
        for ctx, c in counts.items():
            n_ctx = int(c.sum())
            if not ctx or n_ctx < min_count:
                continue
            parent = counts[ctx[1:]]
            p = c / n_ctx
            q = parent / parent.sum()
            nz = p > 0  # every symbol seen after ctx was also seen after its suffix
            gain = n_ctx / total * float(np.sum(p[nz] * np.log(p[nz] / q[nz])))
            if gain > epsilon:
                significant.add(ctx)
        tree = {s[i:] for s in significant for i in range(len(s) + 1)}
        closed = {s[i:j] for s in tree for i in range(len(s) + 1) for j in range(i, len(s) + 1)}
        states = sorted(closed, key=lambda s: (len(s), s))

        def smoothed(c):
            return (1.0 - n_symbols * gamma) * c / c.sum() + gamma

        dist = np.empty((len(states), n_symbols))
        for i, s in enumerate(states):
            src = next(s[j:] for j in range(len(s) + 1) if s[j:] in tree)
            dist[i] = smoothed(counts[src])
        learnt = np.array([s in tree for s in states])
        log.info("VLMM: %d symbols, %d contexts significant, %d tree nodes, %d PFSA states "
                 "(max memory %d, epsilon %g)", n_symbols, len(significant) - 1, len(tree),
                 len(states), max_memory, epsilon)
        return cls(states, dist, n_symbols, learnt, max_memory, epsilon, min_count, gamma)

    # ------------------------------------------------------------------ automaton
    @property
    def n_states(self) -> int:
        return len(self.states)

    @property
    def depth(self) -> np.ndarray:
        """(Q,) int64 memory length of each state."""
        return np.array([len(s) for s in self.states], dtype=np.int64)

    def initial_state(self, history=()) -> int:
        """State index for a symbol history (oldest first): its longest suffix among the states."""
        h = tuple(int(v) for v in np.asarray(history, dtype=np.int64).reshape(-1))
        if any(v < 0 or v >= self.n_symbols for v in h):
            raise ValueError(f"history has symbols outside [0, {self.n_symbols})")
        return self._longest_suffix(h[-self.max_memory:] if self.max_memory else ())

    def next_distribution(self, state) -> np.ndarray:
        """Next-symbol probabilities: (K,) for an int state, (N, K) for (N,) states."""
        return self.next_dist[state]

    def step(self, state, symbol):
        """Next state(s) after emitting ``symbol``; works element-wise on int arrays."""
        return self.trans[state, symbol]

    def states_along(self, sequence) -> np.ndarray:
        """(n,) int64 state *before* each symbol of ``sequence``, starting from the empty state."""
        seq = _check_sequences([sequence], self.n_symbols)[0]
        out = np.empty(seq.size, dtype=np.int64)
        q = 0
        for i, b in enumerate(seq):
            out[i] = q
            q = self.trans[q, b]
        return out

    def sample(self, rng: np.random.Generator, n: int, state: int | None = None) -> np.ndarray:
        """Generate ``n`` symbols by traversing the automaton.

        Parameters
        ----------
        rng : numpy.random.Generator
        n : int, number of symbols.
        state : int or None, start state (None: the empty state, i.e. no history).

        Returns
        -------
        (n,) int64 symbols.
        """
        q = 0 if state is None else int(state)
        u = rng.random(int(n))
        out = np.empty(int(n), dtype=np.int64)
        for i in range(int(n)):
            b = min(int(np.searchsorted(self._cdf[q], u[i], side="right")), self.n_symbols - 1)
            out[i] = b
            q = self.trans[q, b]
        return out

    def log_likelihood(self, sequences, base: float = 2.0) -> tuple[float, int]:
        """Total log probability (in ``base``) of the sequences and their number of symbols.

        Each sequence starts from the empty state.
        """
        seqs = _check_sequences(sequences, self.n_symbols)
        total, n = 0.0, 0
        for s in seqs:
            if s.size == 0:
                continue
            q = self.states_along(s)
            total += float(np.sum(np.log(self.next_dist[q, s])))
            n += s.size
        return total / np.log(base), n

    def entropy(self, sequences, base: float = 2.0) -> float:
        """Model entropy (Caillette et al. eq. 2): ``-1/n sum_i log P(k_i | q_i)``.

        Parameters
        ----------
        sequences : list of 1-D int arrays (or one array).
        base : logarithm base (2: bits per symbol).

        Returns
        -------
        float, per-symbol negative mean log-likelihood (inf if a symbol has probability 0).
        """
        ll, n = self.log_likelihood(sequences, base)
        if n == 0:
            raise ValueError("entropy of an empty set of sequences")
        return -ll / n

    # ------------------------------------------------------------------ serialisation
    def tree_dict(self) -> dict:
        """JSON-serialisable description of the automaton (everything but ``next_dist``)."""
        return {"n_symbols": self.n_symbols, "max_memory": self.max_memory,
                "epsilon": self.epsilon, "min_count": self.min_count, "gamma": self.gamma,
                "states": [list(s) for s in self.states],
                "learnt": [bool(v) for v in self.learnt]}

    @classmethod
    def from_tree(cls, tree: dict, next_dist) -> "Vlmm":
        """Rebuild from :meth:`tree_dict` output and ``next_dist``; ValueError names the field."""
        if not isinstance(tree, dict):
            raise ValueError("vlmm tree must be a JSON object")
        for key in ("n_symbols", "max_memory", "states"):
            if key not in tree:
                raise ValueError(f"vlmm tree field {key!r} is missing")
        states = tree["states"]
        if not isinstance(states, list) or not all(
                isinstance(s, list) and all(isinstance(v, int) and not isinstance(v, bool)
                                            for v in s) for s in states):
            raise ValueError("vlmm tree field 'states' must be a list of integer lists")
        for key in ("n_symbols", "max_memory", "min_count"):
            v = tree.get(key, 1)
            if not isinstance(v, int) or isinstance(v, bool) or v < 0:
                raise ValueError(f"vlmm tree field {key!r} must be a non-negative integer")
        learnt = tree.get("learnt")
        if learnt is not None and not (isinstance(learnt, list) and len(learnt) == len(states)):
            raise ValueError("vlmm tree field 'learnt' must be a list with one flag per state")
        try:
            return cls(states, next_dist, tree["n_symbols"], learnt, tree["max_memory"],
                       float(tree.get("epsilon", 0.0)), tree.get("min_count", 1),
                       float(tree.get("gamma", 0.0)))
        except (TypeError, ValueError) as e:
            raise ValueError(f"invalid vlmm: {e}") from None
