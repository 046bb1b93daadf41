"""Loss-spike monitor: how far a training loss jumps above its own recent typical value.

A *spike* is an iteration whose total loss is many times the running median of the losses just before
it. The median (not the mean) is the reference so that one spike does not hide the next; the window
holds the last ``window`` iterations. Because the regularisers switch on at one iteration (GOF: 15 000)
and change what the loss measures, the caller :meth:`LossSpikeMonitor.restart`s the window there: a
spike compares like with like.

``metrics.json`` reports :meth:`LossSpikeMonitor.report` as ``loss_spikes``: the largest ratio after
``warmup`` iterations, where and in which view it happened with the loss terms at that iteration, and
how many iterations exceeded ``threshold`` × their running median.

The running median mixes views, and with the distortion term some views carry a loss many times the
others' *at every visit* (a hard view, not an instability). So the monitor also keeps, per view, the
median of that view's last ``view_window`` losses and reports the largest jump of a view's loss over its
own median (``max_view_ratio``: a true spike, where training suddenly breaks on a view it fitted) and the
spread of the per-view medians (``view_median_spread``: hardest view's median / overall median). The first
``max_events`` per-view spikes are listed in ``view_spikes`` (iteration, view, ratio, terms), each with what the
caller attaches to it (the trainer: which Gaussians sat right in front of that camera, :mod:`gof_warp.training.near_camera`).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np


@dataclass
class SpikeRecord:
    ratio: float
    iteration: int
    view: str
    loss: float
    median: float
    terms: dict


class LossSpikeMonitor:
    """Running-median spike detector (plain-data state for checkpoints).

    Args:
        window: iterations in the running median (≥ 10).
        warmup: iterations before which nothing is recorded (the issue's "after iteration 1,000").
        threshold: a ratio above this counts as a spike.
        min_history: ratios are recorded only once the window holds this many losses.
        view_window, view_min_history: the same two for each view's own losses.
        max_events: how many per-view spikes ``view_spikes`` lists (all are counted).
    """

    def __init__(self, window: int = 200, warmup: int = 1000, threshold: float = 10.0, min_history: int = 50,
                 view_window: int = 8, view_min_history: int = 3, max_events: int = 20):
        if window < 10 or min_history < 1 or min_history > window or threshold <= 1 or not (
                1 <= view_min_history <= view_window) or max_events < 0:
            raise ValueError(f"LossSpikeMonitor: need window >= 10, 1 <= min_history <= window, threshold > 1, "
                             f"1 <= view_min_history <= view_window, max_events >= 0; got window={window}, "
                             f"min_history={min_history}, threshold={threshold}, view_window={view_window}, "
                             f"view_min_history={view_min_history}, max_events={max_events}")
        self.window, self.warmup, self.threshold, self.min_history = window, warmup, threshold, min_history
        self.recent: deque[float] = deque(maxlen=window)
        self.worst: SpikeRecord | None = None
        self.count_over = 0
        self.checked = 0
        self.view_window, self.view_min_history = view_window, view_min_history
        self.per_view: dict[str, deque[float]] = {}
        self.worst_view: SpikeRecord | None = None
        self.view_count_over = 0
        self.max_events = max_events
        self.events: list[dict] = []
        self.last_view_spike: dict | None = None  # the event the last update added (None: it added none)

    def restart(self) -> None:
        """Forget the windows (the loss's definition changed, e.g. the regularisers switched on)."""
        self.recent.clear()
        self.per_view.clear()

    def update(self, iteration: int, loss: float, view: str = "", terms: dict | None = None) -> float | None:
        """Record one iteration's total loss; returns its ratio to the running median (None before
        there is enough history or during warm-up). Non-finite losses are the trainer's to stop on."""
        ratio = None
        self.last_view_spike = None
        if iteration > self.warmup and len(self.recent) >= self.min_history:
            median = float(np.median(np.fromiter(self.recent, dtype=np.float64)))
            if median > 0:
                ratio = loss / median
                self.checked += 1
                if ratio > self.threshold:
                    self.count_over += 1
                if self.worst is None or ratio > self.worst.ratio:
                    self.worst = SpikeRecord(ratio, iteration, view, loss, median, dict(terms or {}))
        self.recent.append(float(loss))
        if view:
            own = self.per_view.setdefault(view, deque(maxlen=self.view_window))
            if iteration > self.warmup and len(own) >= self.view_min_history:
                median = float(np.median(np.fromiter(own, dtype=np.float64)))
                if median > 0:
                    r = loss / median
                    self.view_count_over += int(r > self.threshold)
                    if r > self.threshold and len(self.events) < self.max_events:
                        self.last_view_spike = {"iteration": iteration, "view": view, "ratio": round(r, 3),
                                                "loss": round(float(loss), 6), "view_median": round(median, 6),
                                                "terms": {k: round(float(x), 6) for k, x in (terms or {}).items()}}
                        self.events.append(self.last_view_spike)
                    if self.worst_view is None or r > self.worst_view.ratio:
                        self.worst_view = SpikeRecord(r, iteration, view, loss, median, dict(terms or {}))
            own.append(float(loss))
        return ratio

    def view_median_spread(self) -> float | None:
        """The hardest view's median loss over the median of all views' medians (None without views)."""
        meds = [float(np.median(np.fromiter(d, dtype=np.float64))) for d in self.per_view.values() if d]
        if not meds or float(np.median(meds)) <= 0:
            return None
        return max(meds) / float(np.median(meds))

    def report(self) -> dict:
        w, v, spread = self.worst, self.worst_view, self.view_median_spread()
        return {"window": self.window, "after_iteration": self.warmup, "threshold": self.threshold,
                "iterations_checked": self.checked, "count_over_threshold": self.count_over,
                "max_ratio": None if w is None else round(w.ratio, 3),
                "at_iteration": None if w is None else w.iteration, "view": None if w is None else w.view,
                "loss": None if w is None else round(w.loss, 6), "running_median": None if w is None else round(w.median, 6),
                "terms": {} if w is None else {k: round(v, 6) for k, v in w.terms.items()},
                "view_window": self.view_window, "view_count_over_threshold": self.view_count_over,
                "max_view_ratio": None if v is None else round(v.ratio, 3),
                "max_view_ratio_at": None if v is None else {"iteration": v.iteration, "view": v.view,
                                                             "loss": round(v.loss, 6), "view_median": round(v.median, 6),
                                                             "terms": {k: round(x, 6) for k, x in v.terms.items()}},
                "view_median_spread": None if spread is None else round(spread, 3),
                "view_spikes": [dict(e) for e in self.events]}

    def state_dict(self) -> dict:
        rec = lambda w: None if w is None else [w.ratio, w.iteration, w.view, w.loss, w.median, dict(w.terms)]  # noqa: E731
        return {"recent": list(self.recent), "count_over": self.count_over, "checked": self.checked,
                "worst": rec(self.worst), "per_view": {k: list(d) for k, d in self.per_view.items()},
                "worst_view": rec(self.worst_view), "view_count_over": self.view_count_over,
                "events": [dict(e) for e in self.events]}

    def load_state_dict(self, state: dict) -> None:
        self.recent = deque((float(x) for x in state["recent"]), maxlen=self.window)
        self.count_over, self.checked = int(state["count_over"]), int(state["checked"])
        rec = lambda w: None if w is None else SpikeRecord(float(w[0]), int(w[1]), str(w[2]), float(w[3]),  # noqa: E731
                                                           float(w[4]), dict(w[5]))
        self.worst = rec(state["worst"])
        self.worst_view = rec(state.get("worst_view"))  # absent in checkpoints written before per-view tracking
        self.per_view = {str(k): deque((float(x) for x in d), maxlen=self.view_window)
                         for k, d in state.get("per_view", {}).items()}
        self.view_count_over = int(state.get("view_count_over", 0))
        self.events = [dict(e) for e in state.get("events", [])]  # absent in checkpoints before the event list
