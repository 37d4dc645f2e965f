import numpy as np
import pytest

from capstan.models.common.errors import DataFormatError
from capstan.models.common.measurement_table import MeasurementTable, read_table, write_table


def test_roundtrip_keeps_columns_and_sidecar(tmp_path):
    t = np.arange(5) * 1e-3
    tab = MeasurementTable({"t": t, "tau_in": np.sin(t), "temperature": t * 2},
                           {"r_in": 0.04, "environment": {"k_out": 20.0, "b_out": 2.0}})
    path = write_table(tab, tmp_path / "run.csv")
    back = read_table(path)
    assert list(back.columns)[:2] == ["t", "tau_in"]
    np.testing.assert_allclose(back["tau_in"], np.sin(t), rtol=1e-8)
    np.testing.assert_allclose(back["temperature"], t * 2)
    assert back.meta["r_in"] == 0.04
    assert back.meta["environment"] == {"k_out": 20.0, "b_out": 2.0}
    assert back.meta["units"]["tau_in"] == "Nm"


@pytest.mark.parametrize("text,match", [
    ("tau_in\n1\n", "'t' missing"),
    ("t,q_in\n0,1\n", "torque column"),
    ("t,tau_in\n0,1\n0,2\n", "strictly increasing"),
    ("t,tau_in\n0,1\n1,abc\n", ":3: not a number"),
    ("t,tau_in\n0,1\n1\n", "1 fields"),
    ("t,tau_in\n0,1\n1,nan\n", "non-finite"),
])
def test_bad_tables_raise_clear_errors(tmp_path, text, match):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(DataFormatError, match=match):
        read_table(p)
