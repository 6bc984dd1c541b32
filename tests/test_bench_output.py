"""`make bench` prints each row as soon as it is measured (not the whole table at the end, after minutes of silence)."""

from __future__ import annotations

import types

import benchmarks.__main__ as bench


def test_each_row_is_printed_before_the_next_benchmark_starts(monkeypatch, capsys):
    seen_before_second = []

    def first_rows():
        return [("first row", 1.5, "<= 2", "1 ms")]

    def second_rows():
        seen_before_second.append(capsys.readouterr().out)
        return [("second row", 0.5, "<= 1", "2 ms")]

    monkeypatch.setattr(bench, "BENCHMARKS", (types.SimpleNamespace(rows=first_rows), types.SimpleNamespace(rows=second_rows)))
    bench.main()
    (before,) = seen_before_second
    assert "first row" in before and "1.50" in before and "second row" not in before
    assert "second row" in capsys.readouterr().out
