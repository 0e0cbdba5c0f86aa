"""Presses that diverged at their batch's planned substeps, pressed again at twice them: one batch's at
once (BatchPalpation.result_from), or many batches' gathered into one press (a dataset's units).

A press that diverges (solvers.stepper.diverged_rows) is pressed again from rest at twice the
substeps of the batch it diverged in, on the same model, rings, frame, kernel, probe and press, up to
REPRESSES times (BatchPalpation.represses). A PressAgain holds what that takes, copied when the press
is read (the batch's arrays are reused by its next build); press_together presses the PressAgains of
one kind (their batches' configurations, press and substeps equal) as one batch and puts each row's
result into the BatchResult it came from. Each palpation of a batch is pressed on its own (the
kernels share nothing between palpations), so a row pressed again alone, with its batch's other
diverged rows, or with other batches' gives the same numbers on the CPU (tests/test_item_batch.py).
Gathering matters on a GPU, where a press of a few palpations costs as long as one of thousands: the
liver dataset's 83 presses pressed again one chunk at a time kept the device idle for 13 s.
"""

from __future__ import annotations

import numpy as np

RESULT_ROWS = ("peak_force", "hold_force", "recovery_error", "region_vertices", "free_vertices", "substeps", "ring_gap")
"""BatchResult's per-palpation fields that a press again replaces (its records too)."""


class PressAgain:
    """Rows `rows` of `result` (a BatchResult of `batch`'s press, read) to press again at twice `batch`'s
    substeps: the batch's configuration (its sibling), its press and each row's contact (and item) as they
    were when the press was read."""

    def __init__(self, batch, result, rows: np.ndarray):
        self.result, self.rows = result, np.asarray(rows)
        self.substeps = 2 * batch.substeps
        self.make = lambda: batch._sibling(self.substeps)
        self.contacts = batch._row_columns(self.rows)
        """Arguments of the sibling's build after (vertices, depth): () or (items,), one entry a row."""
        self.vertices = batch.vertices[self.rows].copy()
        self.depth, self.press_args = batch.depth, batch.press_args
        self.represses = batch.represses - 1
        self.critical_dt, self.critical_dt_bound, self.region_table = batch.critical_dt, batch.critical_dt_bound, batch.region_table
        self.item_critical_dt = dict(getattr(batch, "item_critical_dt", {}))
        kw = batch._sibling_kw(self.substeps)
        config = tuple((k, v if isinstance(v, (int, float, str, type(None))) else id(v)) for k, v in sorted(kw.items()))
        self.key = (type(batch), config, self.press_args, self.represses, id(self.region_table), self.critical_dt_bound)
        """PressAgains of one key press together: their batches' configurations (the sibling's), press and substeps equal."""

    def fill(self, redo, begin: int) -> None:
        """Put rows begin.. of `redo` (the BatchResult of the press again) into this one's rows of its result."""
        end = begin + len(self.rows)
        for name in RESULT_ROWS:
            if getattr(self.result, name) is not None:
                getattr(self.result, name)[self.rows] = getattr(redo, name)[begin:end]
        for name, values in redo.records.items():
            self.result.records[name][self.rows] = values[begin:end]
        self.result.again = None


def press_together(requests: list) -> int:
    """Press the rows of `requests` (PressAgains) again, those of one key as one batch, each row's result
    put back into its own BatchResult; a press that diverges again is pressed again itself (REPRESSES),
    or raises SimulationDiverged. Returns how many rows were pressed again."""
    groups: dict = {}
    for r in requests:
        groups.setdefault(r.key, []).append(r)
    for group in groups.values():
        first = group[0]
        again = first.make()
        again.region_table, again.critical_dt_bound, again.represses = first.region_table, first.critical_dt_bound, first.represses
        again.known_critical_dt = min(r.critical_dt for r in group)
        if hasattr(again, "item_critical_dt"):  # an ItemBatch: each item's critical step, for its errors
            merged: dict = {}
            for r in group:
                for k, dt in r.item_critical_dt.items():
                    merged[k] = min(dt, merged.get(k, dt))
            again.item_critical_dt = merged
        contacts = [np.concatenate(c) for c in zip(*(r.contacts for r in group))]
        again.build(np.concatenate([r.vertices for r in group]), first.depth, *contacts).plan()
        redo = again.press(*first.press_args)
        begin = 0
        for r in group:
            r.fill(redo, begin)
            begin += len(r.rows)
    return sum(len(r.rows) for r in requests)
