"""The ΔT measurement of section VI for the console's ΔT page: the run is
:func:`sync.experiment.record_sine` and :func:`~sync.experiment.analyse` on the console's own
connections (it holds control already); this module turns the result into what the page plots,
Fig. 6 (y^R and y^S against time) and Fig. 7 (MSE against ΔT)."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from sync.experiment import DelayResult, judge

__all__ = ["MAX_PLOT_POINTS", "result_json"]

#: Points per plotted signal sent to the browser (a 10 s run at 250 Hz has 2500).
MAX_PLOT_POINTS = 1500


def _series(t: npt.NDArray[np.float64], y: npt.NDArray[np.float64], t0: float) -> list[list[float]]:
    step = max(1, -(-t.size // MAX_PLOT_POINTS))
    return [
        [round(float(a - t0), 5), round(float(b), 5)]
        for a, b in zip(t[::step], y[::step], strict=True)
    ]


def result_json(r: DelayResult) -> dict[str, Any]:
    """ΔT, the residuals, the verdict, and the data of Figs. 6 and 7."""
    verdict = judge(r)
    d, est = r.data, r.estimate
    return r.summary() | {
        "trusted": verdict.ok,
        "reasons": list(verdict.reasons),
        "fig6": {
            "robot": _series(d.t_robot, d.y_robot, d.t_start),
            "sensor": _series(d.t_trigger, d.y_sensor, d.t_start),
        },
        "fig7": [
            [round(float(s * 1e3), 4), float(m * 1e6)]
            for s, m in zip(est.shifts_s, est.mse, strict=True)
        ],
    }
