"""The rules of the values a command takes, each read by its flag and by a data file's loader alike.

A rule is one object: called on a flag's text as an argparse `type=` (IntRule, NumberRule) or `parse`d from a
comma-separated flag value (ListRule), and asked for the `problem` of a value a data file gives (the studies' TOML
profiles, read by studies/engine/catalogue.Entry.value), so that a profile takes no value its flag refuses and the
words of a refusal are the same. validation.py holds the commands' other checks and gives these under its own name.
"""

from __future__ import annotations

import argparse
import dataclasses
import decimal
import math
from collections.abc import Sequence
from typing import Any

from coopsumo.errors import UsageError


def as_float(value: Any) -> float:
    """float(value) of a number read back, where a whole number too large for a float (400 digits in a record or a
    profile) is +-inf: outside every finite limit, so refused as such, never an OverflowError."""
    try:
        return float(value)
    except OverflowError:
        return math.inf if value > 0 else -math.inf


def shown(value: Any, width: int = 40) -> str:
    """repr(value) cut to `width` characters (a 400-digit number ends in '...')."""
    try:
        text = repr(value)
    except ValueError:  # an integer beyond the digits Python converts to text
        text = f"an integer of about {int(value.bit_length() * 0.30103)} digits"
    return text if len(text) <= width else text[: width - 3] + "..."


def int_range(low: int, high: int | None) -> str:
    return f"an integer from {low} to {high}" if high is not None else f"an integer >= {low}"


def _number_range(low: float | None, high: float | None, low_open: bool, high_open: bool) -> str:
    lo = "" if low is None else f"{'>' if low_open else '>='} {low:g}"
    hi = "" if high is None else f"{'<' if high_open else '<='} {high:g}"
    return "a finite number" + (f" {lo}" if lo else "") + (" and" if lo and hi else "") + (f" {hi}" if hi else "")


def int_problem(value: int, low: int, high: int | None = None) -> str | None:
    """None when low <= value <= high, else the allowed range in words."""
    return None if low <= value and (high is None or value <= high) else int_range(low, high)


def number_problem(value: float, low: float | None = None, high: float | None = None,
                   low_open: bool = False, high_open: bool = False) -> str | None:  # fmt: skip
    """None when value is finite and inside the bounds (open or closed), else the allowed range in words."""
    ok = math.isfinite(value)
    ok = ok and (low is None or (value > low if low_open else value >= low))
    ok = ok and (high is None or (value < high if high_open else value <= high))
    return None if ok else _number_range(low, high, low_open, high_open)


def ascii_text(text: str) -> str:
    """`text`, a flag's number, when it is written in ASCII without '_'; ValueError otherwise. int() and float() read
    '٣', '１００' and '1_0' as 3, 100 and 10, which the records refuse (digits): a flag takes what a record takes
    (issue 82, probe 13, F15: `--lanes ٣` ran 3 lanes, `--seed 1_0` seed 10)."""
    if not text.isascii() or "_" in text:
        raise ValueError(f"not a number written in ASCII digits: {text!r}")
    return text


def int_flag(text: str) -> int:
    """A `type=` for an integer flag without bounds of its own: int() of ASCII text (ascii_text)."""
    try:
        return int(ascii_text(text))
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid int value: {text!r}") from None


def decimal_outside(text: str, low: float | None, high: float | None, low_open: bool = False,
                    high_open: bool = False) -> bool:  # fmt: skip
    """True when the number `text` names, read as a decimal, lies outside the bounds though the float it rounds to
    may not: `--t-up 3600.00000000000001` is 3600.0 as a float, inside a limit of 3600 (issue 82, probe 13, F16). The
    bounds are read as the shortest decimal of their float (0.1 as 0.1, not 0.1000000000000000055...)."""
    try:
        value = decimal.Decimal(text.strip())
    except (decimal.InvalidOperation, ValueError):
        return False
    if not value.is_finite():
        return False
    below = low is not None and (value <= decimal.Decimal(repr(float(low))) if low_open
                                 else value < decimal.Decimal(repr(float(low))))  # fmt: skip
    above = high is not None and (value >= decimal.Decimal(repr(float(high))) if high_open
                                  else value > decimal.Decimal(repr(float(high))))  # fmt: skip
    return bool(below or above)


class IntRule:
    """An integer field's rule, read by its flag (an argparse `type=`: the rule is called on the flag's text) and by
    a data file's loader (`problem` on the value read, catalogue.Entry.value), so that a profile in a file takes no
    value its flag refuses: low <= value <= high; note is added to the range (e.g. its reason)."""

    __name__ = "integer"

    def __init__(self, low: int, high: int | None = None, note: str = "") -> None:
        self.low, self.high, self.note = low, high, note

    def words(self) -> str:
        return f"{int_range(self.low, self.high)}{self.note}"

    def __call__(self, text: str) -> int:
        try:
            value = int(ascii_text(text))
        except ValueError:
            value = None
        if value is None or int_problem(value, self.low, self.high):
            raise argparse.ArgumentTypeError(f"must be {self.words()}, got {text!r}")
        return value

    def problem(self, value: int) -> str | None:
        """None when value is inside the range, else "must be ..., got VALUE" (a data file's value)."""
        return f"must be {self.words()}, got {shown(value)}" if int_problem(value, self.low, self.high) else None


def integer(low: int, high: int | None = None, note: str = "") -> IntRule:
    """A `type=` for an integer flag in [low, high]; note is added to the range (e.g. its reason)."""
    return IntRule(low, high, note)


class NumberRule:
    """A number field's rule, read by its flag (`type=`) and by a data file's loader (`problem`), as IntRule: finite
    and inside the bounds (open or closed)."""

    __name__ = "number"

    def __init__(self, low: float | None = None, high: float | None = None, low_open: bool = False,
                 high_open: bool = False, note: str = "") -> None:  # fmt: skip
        self.low, self.high, self.low_open, self.high_open, self.note = low, high, low_open, high_open, note

    def _problem(self, value: float) -> str | None:
        return number_problem(value, self.low, self.high, self.low_open, self.high_open)

    def __call__(self, text: str) -> float:
        if problem := self._text_problem(text):
            raise argparse.ArgumentTypeError(problem)
        return float(text)

    def _text_problem(self, text: str) -> str | None:
        """Why the number `text` breaks the rule ("must be ..., got TEXT" as given), or None: read as its decimal
        (decimal_outside: over a limit by less than a float's precision is outside), a nonzero text float() reads
        as 0 refused (too_small)."""
        try:
            value = float(ascii_text(text))
        except ValueError:
            value = math.nan
        if decimal_outside(text, self.low, self.high, self.low_open, self.high_open):
            value = math.nan  # over a limit by less than a float's precision: the range's words, the text as given
        if problem := self._problem(value):
            return f"must be {problem}{self.note}, got {text!r}"
        if too_small(text):
            return f"must be {self._problem(math.nan)}{self.note}, got {text!r}, {TOO_SMALL}"
        return None

    def problem(self, value: Any) -> str | None:
        """None when value is finite and inside the bounds, else "must be ..., got VALUE" (a data file's value; a
        Written one, a TOML file's, judged by its text as the flag judges its text)."""
        if isinstance(value, Written):
            return self._text_problem(value.text)
        problem = self._problem(as_float(value))
        return f"must be {problem}{self.note}, got {shown(value)}" if problem else None


TOO_SMALL = "which is too small for a float and would be taken as 0 (give 0, or a number from 1e-308)"
"""why a float flag refuses a text float() reads as 0 that is not 0 (1e-400; issue 82, probe 7, I16: --w-speed 1e-400
trained the speed term off)"""


def float_flag(text: str) -> float:
    """A `type=` for a float flag without bounds of its own (a learner flag, checked by its DQNConfig field's limits):
    float(text), refused when text names a number too small for a float, which float() reads as 0 (_zero_text)."""
    try:
        value = float(ascii_text(text))
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid float value: {text!r}") from None
    if too_small(text):
        raise argparse.ArgumentTypeError(f"got {text!r}, {TOO_SMALL}")
    return value


def too_small(text: str) -> bool:
    """True when `text` names a number that is not 0 but that float() reads as 0 ('1e-400'), which no float holds:
    the one rule of every number read from text, a flag's, a list flag's item, a policy parameter's or a data file's
    (issue 82, probe 14, F7: `--alphas 1e-400,1` ran alpha 0). '0', '-0.0' and '0e5' say 0 themselves."""
    try:
        if float(text) != 0:
            return False
        return decimal.Decimal(text.strip()) != 0
    except (decimal.InvalidOperation, ValueError):
        return False  # a form float or Decimal does not read: left to float's reading


class Written(float):
    """A float a data file gives, with the text it is written as (`text`; a TOML file's, catalogue.read_toml), so that
    its rule judges what the file says, as a flag's rule judges the flag's text: 1000.00000000000000001 is over a limit
    of 1000 and 1e-400 is not 0, though their floats are 1000.0 and 0.0 (issue 82, probe 14, F8 and F7). Its repr is
    the text: a refusal shows the value as given. float(value) is the plain float."""

    text: str

    def __new__(cls, text: str) -> Written:
        value = super().__new__(cls, text)
        value.text = text
        return value

    def __repr__(self) -> str:
        return self.text


def number(low: float | None = None, high: float | None = None, low_open: bool = False, high_open: bool = False,
           note: str = "") -> NumberRule:  # fmt: skip
    """A `type=` for a finite float flag inside the bounds."""
    return NumberRule(low, high, low_open, high_open, note)


def parse_number(text: str) -> float:
    """'1/8' -> 0.125, '2.5' -> 2.5; ValueError otherwise (also for a zero denominator), TooSmall for a number too
    small for a float (too_small: '1e-400', '1e-400/1'), which float() would read as 0."""
    text = ascii_text(text.strip())
    if "/" in text:
        num, den = text.split("/", 1)
        try:
            value = float(num) / float(den)
        except ZeroDivisionError:
            raise ValueError(f"division by zero in {text!r}") from None
        if value == 0 and (too_small(num) or float(num) != 0):  # 1e-400/1, 1e-200/1e200: no float holds them
            raise TooSmall(text)
        return value
    if too_small(text):
        raise TooSmall(text)
    return float(text)


class TooSmall(ValueError):
    """A number's text names a number too small for a float (too_small): parse_number's refusal, its text the item."""

    def __init__(self, text: str) -> None:
        super().__init__(text)
        self.text = text


def split_list(flag: str, text: str) -> list[str]:
    """The items of a comma-separated flag value, spaces around them dropped; UsageError naming the flag for an
    empty value or an empty item (',,' or a ',' at either end) and for an item given twice."""
    items = [x.strip() for x in text.split(",")]
    if not text.strip():
        raise UsageError(f"{flag} is empty; give a comma-separated list")
    if any(not x for x in items):
        raise UsageError(f"{flag} has an empty item in {text!r} (',,' or a ',' at either end)")
    twice = sorted({x for x in items if items.count(x) > 1})
    if twice:
        raise UsageError(f"{flag} lists {', '.join(twice)} more than once in {text!r}")
    return items


@dataclasses.dataclass(frozen=True)
class ListRule:
    """The rule of a list of numbers a command takes (a study's axis), read by its flag (`parse`, a comma-separated
    value, fractions like 1/8 allowed) and by a data file's loader (`problem` on the list read,
    catalogue.Entry.value), so that a profile in a file takes no list its flag refuses: finite numbers inside the
    bounds, whole numbers where `whole`, from `least` to `most` of them, no value twice in any form (0 and -0, 1 and
    1.0: a list never merges them silently); note is added to the range in the message."""

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    whole: bool = False
    note: str = ""
    least: int = 1
    most: int | None = None

    def values_problem(self, values: Sequence[float], items: Sequence[str], shown: str, form: str) -> str | None:
        """Why `values` (written as `items`, the whole as `shown`) break the rule, in words after the field's name
        ("must be a list of ..., got [nan]"), or None."""
        problem = next((p for v in values if (p := number_problem(v, self.low, self.high, self.low_open))), None)
        if len(values) < self.least or problem or (self.whole and any(v != int(v) for v in values)):
            if self.whole and self.low is not None and self.high is not None and not self.low_open:
                rng = f"integers from {self.low:.0f} to {self.high:.0f}"
            else:
                kind = "whole numbers" if self.whole else "numbers"
                rng = (problem or _number_range(self.low, self.high, self.low_open, False)).replace(
                    "a finite number", f"finite {kind}")  # fmt: skip
            return f"must be {form} of {rng}{self.note}, got {shown}"
        if self.most is not None and len(values) > self.most:
            return f"must be {form} of at most {self.most} values, got {len(values)}"
        if twice := twice_at(values):
            return f"gives the same value twice in {shown}: {items[twice[0]]} and {items[twice[1]]}"
        return None

    def parse(self, flag: str, text: str) -> tuple[float, ...]:
        """A flag's comma-separated value (split_list, each item a number); UsageError naming the flag otherwise."""
        parts = split_list(flag, text)
        small = ""
        try:
            values = tuple(parse_number(x) for x in parts)
        except TooSmall as err:
            values, small = (math.nan,), f": {err.text!r} is{TOO_SMALL.removeprefix('which is')}"
        except ValueError:
            values = (math.nan,)  # not a number: the range's words
        if any(decimal_outside(x, self.low, self.high, self.low_open) for x in parts):
            values = (math.nan,)  # over a limit by less than a float's precision (decimal_outside)
        if problem := self.values_problem(values, [repr(x) for x in parts], repr(text), "a comma-separated list"):
            raise UsageError(f"{flag} {problem}{small}")
        return values

    def problem(self, values: Sequence[float]) -> str | None:
        """Why a data file's list breaks the rule ("must be a list of ..., got [nan]"), or None."""
        items = [shown(v) for v in values]  # a 400-digit number shortened, any other as repr gives it
        floats = [as_float(v) for v in values]
        written = [v.text for v in values if isinstance(v, Written)]  # a TOML file's, judged by its text as a flag's
        small = next((f": {x} is{TOO_SMALL.removeprefix('which is')}" for x in written if too_small(x)), "")
        if small or any(decimal_outside(x, self.low, self.high, self.low_open) for x in written):
            floats = [math.nan]
        if problem := self.values_problem(floats, items, f"[{', '.join(items)}]", "a list"):
            return problem + small
        return None


def number_list(flag: str, text: str, low: float | None = None, high: float | None = None,
                low_open: bool = False, whole: bool = False, note: str = "") -> tuple[float, ...]:  # fmt: skip
    """A comma-separated list of finite numbers (fractions like 1/8 allowed) inside the bounds, not empty
    (ListRule.parse).

    whole: every value must be a whole number; note is added to the range in the message.
    """
    return ListRule(low, high, low_open, whole, note).parse(flag, text)


def twice_at(values: Sequence[object]) -> tuple[int, int] | None:
    """The positions (i, j), i < j, of the first value given twice in `values` (0 and -0, 1 and 1.0 are one value),
    or None."""
    seen = list(values)
    for j, value in enumerate(seen):
        i = seen.index(value)
        if i < j:
            return i, j
    return None


def same_twice(flag: str, text: str, items: Sequence[str], values: Sequence[object]) -> None:
    """UsageError naming the flag and the first value whose items (as written) read as the same value
    (0 and -0, 1 and 1.0, 2 and 02, 1/8 and 0.125): a list never merges them silently."""
    if twice := twice_at(values):
        i, j = twice
        raise UsageError(f"{flag} gives the same value twice in {text!r}: {items[i]!r} and {items[j]!r}")


def names_problem(names: Sequence[str], known: Sequence[str], least: int = 1) -> str | None:
    """Why a data file's list of names (variants, policies) breaks the rule of its flag (name_list: no name twice,
    none outside `known`), or None; at least `least` of them."""
    if len(names) < least:
        return f"must name at least {least} of {', '.join(known)}, got {list(names)!r}"
    if twice := twice_at(names):
        return f"names {names[twice[1]]!r} twice in {list(names)!r}"
    if unknown := [x for x in names if x not in known]:
        return f"names unknown {', '.join(map(repr, unknown))}; expected some of {', '.join(known)}"
    return None


def digits(text: str) -> bool:
    """Whether `text` is a whole number written in ASCII digits only: str.isdigit() also takes '²' or '٣', which
    int() refuses or reads, so a record's counter would pass the check and then end in a traceback (probe 6, H6)."""
    return text.isascii() and text.isdigit()
