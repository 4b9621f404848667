"""explain's scenes come in the ranking table's order: the full scene, then the most influential what-if first."""

from __future__ import annotations

import numpy as np
from conftest import SEVEN, straight, table_of

from lanecast.models.explain import what_if
from lanecast.models.predict import STCNNForecaster
from lanecast.models.reports.explain import scenes
from lanecast.pipeline.make_windows import make_windows


def test_scenes_follow_the_ranking() -> None:
    table = table_of(straight(SEVEN, np.arange(80), vx={2: 24.0}))
    w = make_windows(table, require_future=False, split="none")
    i = int(np.flatnonzero(w.index.column("track_id").to_numpy() == 1)[0])
    forecaster, inputs, present = (
        STCNNForecaster.load(None),
        np.asarray(w.inputs[i]),
        np.asarray(w.present[i]),
    )
    first = what_if(forecaster, inputs, present, [("RL",), ("F",), ("FL",)])
    least_first = [tuple(first.removed[s]) for s in reversed(first.rank())]
    result = what_if(forecaster, inputs, present, least_first)  # given in the opposite of rank order
    ranked = [result.names[s] for s in result.rank()]
    assert ranked == list(reversed(result.names[1:]))
    titles = [scene.title.split(": ", 1)[1] for scene in scenes(result, "t", np.full((5, 2), np.nan))]
    assert titles == ["full scene", *ranked]
