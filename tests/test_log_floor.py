"""The log-size floor analysis (tools/bench/log_floor.py) converts losslessly or says so."""

import numpy as np
import pytest

from capstan.controller.law.records import LOG_FLOAT32_FIELDS
from capstan.tools.bench.logs import (LC_SCALE_N_PER_MV_V, RAD_PER_COUNT, RAD_S_PER_UNIT, RATED_TORQUE_NM,
                                 realistic_records)
from capstan.tools.bench.log_floor import WireScales, column_costs, fixed_point_columns, floor_table

SCALES = WireScales(LC_SCALE_N_PER_MV_V, RAD_PER_COUNT, RAD_S_PER_UNIT, RATED_TORQUE_NM)


@pytest.fixture(scope="module")
def records() -> np.ndarray:
    return realistic_records(1600, seed=3)


def test_fixed_point_columns_reproduce_the_records(records):
    cols = fixed_point_columns(records, LOG_FLOAT32_FIELDS, SCALES)
    assert cols["q_m_rad"].dtype == np.int32
    np.testing.assert_array_equal(cols["q_m_rad"] * RAD_PER_COUNT, records["q_m_rad"])
    np.testing.assert_array_equal(LC_SCALE_N_PER_MV_V * cols["T_up_in_N"].astype(np.float64), records["T_up_in_N"])
    t_ns = cols["t_s"]
    assert np.max(np.abs((t_ns + cols["lc_t_s"]) / 1e9 - records["lc_t_s"])) <= 1e-9


def test_a_value_off_the_wire_grid_is_refused(records):
    bad = records.copy()
    bad["q_m_rad"][10] += 0.3 * RAD_PER_COUNT
    with pytest.raises(ValueError, match="q_m_rad"):
        fixed_point_columns(bad, LOG_FLOAT32_FIELDS, SCALES)


def test_wire_units_compress_better_than_scaled_floats(records):
    fixed = column_costs(fixed_point_columns(records, LOG_FLOAT32_FIELDS, SCALES), 800, 15)
    now = column_costs({"q_m_rad": np.ascontiguousarray(records["q_m_rad"])}, 800, 15)
    assert fixed["q_m_rad"] < 0.5 * now["q_m_rad"]
    rows = floor_table(records, LOG_FLOAT32_FIELDS, SCALES, 800, 15)
    totals = [b for label, b in rows if label.startswith("TOTAL")]
    assert totals[0] > totals[1] > totals[2] > 0
