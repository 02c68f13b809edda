"""When the diagnosis' final calibration may reuse its starting fit's clock search and stages
1-2 (:func:`~mocap_calib.core.pipeline.calibrate.same_first_fits`); that the reuse gives
``calibrate``'s answer exactly is tested in tests/test_diagnose.py."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mocap_calib.core.model.effects import Model
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.calibrate import same_first_fits
from mocap_calib.core.position.graph import Prior


def test_the_first_fits_are_reused_only_where_they_would_be_the_same() -> None:
    """The clock search and stages 1-2 see the model's clock offset and the effects' starting
    values: another timing, other options or a prior on an effect (or other prior objects)
    mean they are fitted again."""
    timed = CalibrationOptions()
    more = replace(timed, model=Model.parse("base+time_offset+accel_delay"))
    assert same_first_fits(timed, more)
    assert not same_first_fits(timed, replace(more, model=Model()))
    assert not same_first_fits(timed, replace(more, gravity=9.79))
    p = Prior("translation", np.array([0.1, 0.0, 0.0]), np.full(3, 1e-3))
    assert same_first_fits(replace(timed, priors=[p]), replace(more, priors=[p]))
    twin = Prior("translation", np.array([0.1, 0.0, 0.0]), np.full(3, 1e-3))
    assert not same_first_fits(replace(timed, priors=[p]), replace(more, priors=[twin]))
    on_effect = Prior("accel_delay", np.array([0.003]), np.array([1e-4]))
    assert not same_first_fits(replace(timed, priors=[on_effect]),
                               replace(more, priors=[on_effect]))
