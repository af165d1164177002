"""How a record's rows are divided for calibration: training, validation folds, and a test part.

Every error the calibration reports is measured on rows that took no part in what it reports:

* the **test** part is never seen by the choice of the effect; ``error_before`` /
  ``error_after`` are measured there (the base and the chosen effect refitted on all the
  development rows);
* the **development** rows (everything else that is used) are cut into ``n_folds``
  validation folds: for each fold the base and every candidate are fitted on the other
  development rows and scored on the fold. The effect named is the one that wins the folds
  consistently (:mod:`.tracing`).

Rows are grouped in **blocks** of ``block_s`` seconds derived from the record (never a
fixed count of samples): ``block_s = max(50 dt, duration / 100)`` -- at least 50 samples,
so a held-out block is a stretch to predict, not a sample to interpolate between its
neighbours at a low rate, and at most ~100 blocks so each fold holds many. Splits:

``"blocks"``
    Blocks labelled by the golden-ratio sequence (not every n-th: a protocol's own period must
    not line its steps up with one fold): a fifth to the test part, the rest spread over the
    folds. The first block always trains (a record from rest takes its virgin branch there).
    Each part of a protocol (sines, holds, chirp) is fitted and tested.
``"forward"``
    Train on the past, predict the future: the last quarter of the record is the test part;
    the development rows are cut into ``n_folds + 1`` contiguous chunks and fold ``k`` trains
    on chunks ``0..k-1`` and validates on chunk ``k`` (expanding windows). For records whose
    later parts excite what earlier parts do not (the protocol's chirp comes last) this can
    only find slow effects.
``"cycles"``
    The first ``train_cycles`` input cycles are the development rows (from the input's second
    reversal: a start transient is left out), everything after is the test part; the folds
    are contiguous chunks of the development rows, each left out in turn.

**Which split by default** (:func:`default_split`): a generic stack (voltage to displacement
only) takes ``"cycles"``; a full PZT plant takes ``"blocks"`` unless ``forward_when_slow``
is set and the candidates include a slow, time-driven effect (``SLOW_EFFECTS``: drift,
creep, leakage, dielectric absorption -- effects whose signature is a trend over the record,
which interleaved blocks let a fit interpolate rather than predict), then ``"forward"``.
``forward_when_slow`` is off by default: measured on the confusion benchmark, the forward
split names fewer effects right on records it did not tune to (README, Calibration), since
the protocols put their fast parts (the chirp) last, where a forward split only tests.
The reason for the split used is returned with it and written to the JSON and the report.
"""

from dataclasses import dataclass

import numpy as np

from .pi_fit import pi_thresholds, split_by_cycles, turning_points

__all__ = ["Split", "make_split", "holdout_mask", "block_length_s", "default_split", "SPLITS", "SLOW_EFFECTS",
           "settled_row"]

SPLITS = ("blocks", "forward", "cycles")
GOLDEN = 0.6180339887498949
#: effects whose signature is a trend over the record (time-driven or a slow response to the
#: input's history): a forward split predicts them, interleaved blocks interpolate them
SLOW_EFFECTS = ("drift", "creep", "leakage", "dielectric_absorption")


def default_split(plant_kind, candidates, forward_when_slow=False):
    """The split a calibration uses when none is asked for, and why.

    Parameters
    ----------
    plant_kind : str
        ``"generic_stack"`` or ``"pzt"`` (:func:`workbench.plant.plant_kind`).
    candidates : iterable of str
        The names of the candidate effects (``Effect.name``) the tracing will try.
    forward_when_slow : bool
        Take ``"forward"`` when a candidate is in ``SLOW_EFFECTS`` (see the module notes:
        off by default, measured worse on the confusion benchmark).

    Returns
    -------
    kind, reason : str, str
    """
    if plant_kind == "generic_stack":
        return "cycles", ("a generic stack is calibrated from its first input cycles and predicts the rest "
                          "(--train-cycles)")
    slow = sorted({str(c) for c in candidates} & set(SLOW_EFFECTS))
    if slow and forward_when_slow:
        return "forward", (f"slow, time-driven candidates ({', '.join(slow)}): trained on the past, the last "
                           f"quarter of the record is predicted")
    if slow:
        return "blocks", (f"interleaved blocks: slow candidates ({', '.join(slow)}) are present, but a forward "
                          f"split (--split forward) named fewer effects right on the confusion benchmark, whose "
                          f"protocols put their fast parts last")
    return "blocks", "interleaved blocks: no slow, time-driven candidate"


def block_length_s(t):
    """Block length in seconds: ``max(50 dt, duration / 100)`` (see the module notes)."""
    t = np.asarray(t, float)
    dur = float(t[-1] - t[0])
    dt = dur / max(t.size - 1, 1)
    return max(50.0 * dt, dur / 100.0)


@dataclass(eq=False)
class Split:
    """Rows of a record by block; ``block[i]`` is row i's block (-1: row unused)."""

    kind: str
    block: np.ndarray            # int per row
    block_s: float
    test_blocks: np.ndarray      # bool per block
    folds: list                  # [(train_blocks bool per block, val_blocks bool per block)]

    @property
    def n_blocks(self):
        return self.test_blocks.size

    def rows(self, blocks):
        """Boolean row mask of the given blocks (a bool array per block)."""
        b = np.asarray(blocks, bool)
        return (self.block >= 0) & b[np.maximum(self.block, 0)]

    @property
    def dev_blocks(self):
        return np.any([tr | va for tr, va in self.folds], axis=0)

    @property
    def train(self):
        """Development rows (every fold's training or validation rows)."""
        return self.rows(self.dev_blocks)

    @property
    def test(self):
        return self.rows(self.test_blocks)


def settled_row(v, n_plays, grid):
    """The first row at which every play a record's input can settle is settled, whatever its state before it.

    A play of threshold ``r`` forgets its initial state once the input has swept ``2 r`` (its running
    maximum minus its running minimum since the start: the rise pushes the state to ``max - r``, the fall
    to ``min + r``, one past the other). The plays are those of the declared grid over the whole record
    (:func:`~workbench.calibrate.pi_fit.pi_thresholds` on ``v``, ``n_plays`` on ``grid``; the base fit's own
    come from its training rows, and a generic stack's are spread again); the record can settle those of
    ``2 r`` at most its span. An amplifier-command record needs it: its plays start at the
    first command value, but where the stack stood is the amplifier's offset and the stack's past, which the
    record does not say (a 0.5 Hz sine from rest through an amplifier of offset +2.7 V: the displacement's
    misfit over the first rise was 6e-8 m against 3.5e-9 m after it, and the lag search on the blocks
    split's training rows kept "no lag"; s22_outsider A3).

    A play short of its sweep by ``d`` has a state off by at most ``d``, so the largest such play counts as
    settled once the sweep is within one grid step of ``2 r`` (``r_k + r_{k-1}``): the grid cannot place a
    threshold more finely. Asked for ``2 r`` exactly, a uniform grid's play at half the span needed the record's
    full span, reached first at the noisiest peak: on a 12 s, 0.55 Hz command from rest the rows left out ran from
    0.91 to 10.91 s over 20 noise draws (review of s24_command); with the step, 0.78 s on every draw.
    """
    v = np.asarray(v, float)
    span = float(np.ptp(v))
    if not span > 0:
        return 0
    r = pi_thresholds(v, n_plays, grid)
    k = int(np.flatnonzero(2.0 * r <= span).max())
    need = float(r[k] + r[k - 1]) if k >= 1 else 0.0
    swept = np.maximum.accumulate(v) - np.minimum.accumulate(v)
    return int(np.argmax(swept >= need)) if need > 0 else 0


def _chunks(dev_idx, n):
    """Contiguous groups of the (sorted) development blocks: ``n`` labels."""
    k = np.arange(dev_idx.size)
    return np.minimum((k * n) // max(dev_idx.size, 1), n - 1)


def make_split(t, v, kind="blocks", n_folds=5, train_cycles=3, block_s=None, start_row=0):
    """The record's :class:`Split` (see the module notes); ``ValueError`` when it cannot be made.

    ``start_row``: the rows before it are unused (block -1) and the split is made on the rest, as if the record
    began there (an amplifier command's rows before :func:`settled_row`)."""
    t = np.asarray(t, float)
    v = np.asarray(v, float)
    if start_row:
        k0 = int(start_row)
        sp = make_split(t[k0:], v[k0:], kind, n_folds, train_cycles, block_s)
        sp.block = np.r_[np.full(k0, -1, int), sp.block]
        return sp
    if kind not in SPLITS:
        raise ValueError(f"split must be one of {', '.join(SPLITS)}, got {kind!r}")
    bs = float(block_s) if block_s else block_length_s(t)
    block = np.floor((t - t[0]) / bs).astype(int)
    nb = int(block.max()) + 1
    if nb < 2 * (n_folds + 1):
        raise ValueError(f"the record ({t[-1] - t[0]:.3g} s) makes only {nb} blocks of {bs:.3g} s; "
                         f"{2 * (n_folds + 1)} are needed for {n_folds} folds and a test part")
    test = np.zeros(nb, bool)
    label = np.full(nb, -1)                 # fold of each development block
    if kind == "blocks":
        u = np.mod((np.arange(nb) + 1) * GOLDEN, 1.0)
        test = u < 0.2
        test[0] = False
        label = np.where(test, -1, np.minimum(((u - 0.2) / 0.8 * n_folds).astype(int), n_folds - 1))
        label[0] = np.clip(label[0], 0, n_folds - 1)
        folds = [((label >= 0) & (label != k), label == k) for k in range(n_folds)]
    elif kind == "forward":
        start = (t - t[0]) / (t[-1] - t[0])
        first_of_block = np.array([start[block == b][0] if np.any(block == b) else 1.0 for b in range(nb)])
        test = first_of_block >= 0.75
        dev = np.flatnonzero(~test)
        c = _chunks(dev, n_folds + 1)
        folds = []
        for k in range(1, n_folds + 1):
            tr = np.zeros(nb, bool)
            va = np.zeros(nb, bool)
            tr[dev[c < k]] = True
            va[dev[c == k]] = True
            folds.append((tr, va))
    else:
        first = split_by_cycles(v, train_cycles)
        tp = turning_points(v)
        start = tp[1] if tp.size > 1 else 0
        dev_rows = first & (np.arange(t.size) >= start)
        # blocks cut from the development rows' own start, so the folds tile them
        rel = np.where(dev_rows, t - t[start], -1.0)
        n_dev = int(dev_rows.sum())
        bs = min(bs, (t[first][-1] - t[start]) / (2 * (n_folds + 1))) if n_dev else bs
        block = np.where(dev_rows, np.floor(rel / bs).astype(int), -1)
        n_dev_blocks = int(block.max()) + 1
        after = ~first
        block[after] = n_dev_blocks
        nb = n_dev_blocks + 1
        test = np.zeros(nb, bool)
        test[-1] = True
        dev = np.arange(n_dev_blocks)
        c = _chunks(dev, n_folds)
        folds = [(np.r_[c != k, False], np.r_[c == k, False]) for k in range(n_folds)]
        if not after.any() or n_dev_blocks < n_folds:
            raise ValueError(f"{train_cycles} training cycles leave {int(after.sum())} rows to predict and "
                             f"{n_dev_blocks} development blocks; use fewer training cycles or a longer record")
    return Split(kind, block, bs, test, folds)


def holdout_mask(t, v, split="blocks", block_s=None, every=None, train_cycles=3):
    """Development rows (True) of a record: :attr:`Split.train` of :func:`make_split`.

    Kept for callers of the earlier interface (``every`` is ignored: the test part is a fifth
    of the blocks, see the module notes). ``t`` may be None for a record sampled uniformly
    (the sample index is then its clock: the cycles split needs no time).
    """
    if t is None:
        t = np.arange(len(v), dtype=float)
    return make_split(t, v, kind=split, train_cycles=train_cycles, block_s=block_s).train
