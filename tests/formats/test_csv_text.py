"""CSV cells of floats: the shortest text that reads back to the same float64."""

from __future__ import annotations

import numpy as np

from vibrissa.formats.csv_text import cell, cells


def test_cells_of_an_array_read_back_exactly_and_agree_with_cell() -> None:
    rng = np.random.default_rng(3)
    special = [0.0, -0.0, np.nan, np.inf, -np.inf, 5e-324, np.finfo(float).max, 0.1, 1 / 3]
    values = np.concatenate([rng.normal(size=60) * 10.0 ** rng.integers(-300, 300, 60),
                             special, rng.normal(size=3)]).reshape(-1, 3)
    text = cells(values)
    assert len(text) == len(values) and all(len(row) == 3 for row in text)
    for row, numbers in zip(text, values, strict=True):
        assert row == [cell(v) for v in numbers]
        for word, v in zip(row, numbers, strict=True):
            if np.isnan(v):
                assert word == ""
            else:
                assert float(word) == v and np.signbit(float(word)) == np.signbit(v)
    assert cells(np.array([[-0.0, 0.1]])) == [["-0.0", "0.1"]]
