"""mmdopt.bench.load_results: benchmark tables as pandas DataFrames."""

from __future__ import annotations

import pytest

from mmdopt.bench import load_results
from mmdopt.bench.results import RESULT_COLUMNS, write_results

pd = pytest.importorskip("pandas", reason="pandas is not installed (pip install 'mmdopt[pandas]')")


def _rows(n=3):
    return [
        dict(
            scene=i,
            method=m,
            collision_free=990 + i,
            n_validation=1000,
            progress_m=100.0 + i,
            feasible=True,
            plan_time_s=0.5,
            status="ok",
        )
        for i in range(n)
        for m in ("mmd", "degroot")
    ]


def test_results_csv_round_trips_as_a_dataframe(tmp_path):
    write_results(_rows(), tmp_path / "results.csv")
    df = load_results(tmp_path)
    assert list(df.columns[: len(RESULT_COLUMNS)]) == list(RESULT_COLUMNS)
    assert len(df) == 6
    assert df["collision_free"].dtype.kind == "i" and df["feasible"].dtype == bool
    assert df.groupby("method")["collision_free"].mean()["mmd"] == 991.0
    # a CSV path works too
    assert load_results(tmp_path / "results.csv").equals(df)


def test_several_tables_are_concatenated_with_a_table_column(tmp_path):
    write_results(_rows(1), tmp_path / "results.csv")
    rows = [dict(reduced_set_size=10, n_samples=100, reduced_set_s=0.01, algorithm1_s=0.2)]
    write_results(rows, tmp_path / "timing.csv", list(rows[0]))
    df = load_results(tmp_path)
    assert df.columns[0] == "table"
    assert sorted(df["table"].unique()) == ["results", "timing"]
    only = load_results(tmp_path, table="timing")
    assert len(only) == 1 and "table" not in only.columns


def test_folder_without_tables_is_a_clear_error(tmp_path):
    (tmp_path / "summary.json").write_text("{}")
    with pytest.raises(FileNotFoundError, match="results.csv, reduced_set.csv, timing.csv"):
        load_results(tmp_path)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_results(tmp_path / "nope")
    with pytest.raises(ValueError, match="table must be one of"):
        load_results(tmp_path, table="summary")
