"""A report's figure keeps three significant digits also where rounding carries it to the next
power of ten: 9.996 m prints "10.0", never "10.00"."""

from __future__ import annotations

import pytest

from c3_matcher_tools.run import figure


@pytest.mark.parametrize(
    ("value", "text"),
    [
        (9.996, "10.0"),
        (0.9996, "1.00"),
        (99.96, "100"),
        (-9.996, "-10.0"),
        (0.09996, "0.100"),
        (9.994, "9.99"),
        (0.0004, "0.000"),
    ],
)
def test_a_figure_rounded_up_to_the_next_power_of_ten_keeps_three_digits(
    value: float, text: str
) -> None:
    assert figure(value) == text
