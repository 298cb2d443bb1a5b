"""The field-reader framework every scenario section is read with: a `Section` is a mapping being read,
with typed getters (numbers, whole numbers, strings, arrays of a shape, angles in rad or `_deg`, nested
sections and lists) that record which keys were used; `done()` rejects the rest. Every rejected value
raises ScenarioError with one line "WHERE: FIELD: reason", FIELD a dotted path such as
`arms[0].links[1].box.density`; numbers are real numbers (not booleans or quoted text), finite and at
most MAX_MAGNITUDE in size.
"""

from __future__ import annotations


import numpy as np

from coopsim.core.errors import ScenarioError


REQUIRED = object()


MAX_MAGNITUDE = 1e9             # |x| of any number in a scenario or a torque CSV


def show_value(v, limit: int = 60) -> str:
    """repr(v), cut to about `limit` characters (a value in an error line may be a whole list).

    Args:
        v: any value read from a scenario (a list or mapping longer than `limit` is cut before its repr
            is built).
        limit: the most characters shown; a longer repr ends in "…".

    Returns:
        str: the repr, at most `limit` characters.
    """
    if isinstance(v, (list, dict)) and len(v) > limit:   # never build the repr of a huge value
        v = v[:limit] if isinstance(v, list) else dict(list(v.items())[:limit])
    text = repr(v)
    return text if len(text) <= limit else text[:limit - 1] + "…"


_ALL_NUMBERS = object()


def _first_non_number(v):
    """The first leaf of v (a number or nested lists) that is not a real number (a bool, a string,
    None, a mapping, a date, ...); _ALL_NUMBERS when there is none."""
    stack = [v]
    while stack:
        x = stack.pop()
        if isinstance(x, list):
            stack.extend(reversed(x))
        elif isinstance(x, bool) or not isinstance(x, (int, float)):
            return x
    return _ALL_NUMBERS


def _first_big_int(v):
    """The first int in v (nested lists of numbers) larger than MAX_MAGNITUDE in size, else None."""
    stack = [v]
    while stack:
        x = stack.pop()
        if isinstance(x, list):
            stack.extend(reversed(x))
        elif isinstance(x, int) and abs(x) > MAX_MAGNITUDE:
            return x
    return None


class Section:
    """A mapping being read: typed getters that record which keys were used, `done()` rejects the rest.

    Every getter that refuses a value raises ScenarioError with one line "WHERE: FIELD: reason".

    Args:
        data: the mapping (a dict of the parsed scenario data) this section reads.
        path: the dotted field path of the mapping, e.g. `arms[0].links[1]` ("" for the whole scenario).
        where: the source named at the start of every error line (e.g. the scenario file).

    Attributes:
        data: the mapping read.
        path: its dotted field path ("" at the top).
        where: the error lines' source.
        used: set of the keys read so far (what `done` accepts).

    Raises:
        ScenarioError: `data` is not a mapping.
    """

    def __init__(self, data, path: str, where: str):
        if not isinstance(data, dict):
            raise ScenarioError(f"{where}: {path or 'scenario'}: expected a mapping, got {type(data).__name__}")
        self.data, self.path, self.where, self.used = data, path, where, set()

    def field(self, key: str) -> str:
        """The dotted path of `key` in this section, as the error lines name it.

        Args:
            key: a key of this mapping.

        Returns:
            str: `path.key`, or `key` at the top level.
        """
        return f"{self.path}.{key}" if self.path else key

    def fail(self, key: str, reason: str):
        """Refuse the value under `key`: raise the one-line error "WHERE: FIELD: reason".

        Args:
            key: the key refused.
            reason: why, e.g. "must be positive, got -1.0".

        Raises:
            ScenarioError: always.
        """
        raise ScenarioError(f"{self.where}: {self.field(key)}: {reason}")

    def has(self, key: str) -> bool:
        """Whether the mapping holds `key` (not marked as used).

        Args:
            key: the key looked up.

        Returns:
            bool: True when `key` is present (even with a null value).
        """
        return key in self.data

    def raw(self, key: str, default=REQUIRED):
        """The value under `key` as parsed, unchecked; `key` is marked as used.

        Args:
            key: the key read.
            default: the value of an absent or null key; REQUIRED: the key must be given.

        Returns:
            Any: the value, or `default`.

        Raises:
            ScenarioError: a required key is absent or null.
        """
        self.used.add(key)
        if key not in self.data or self.data[key] is None:
            if default is REQUIRED:
                self.fail(key, "missing required field")
            return default
        return self.data[key]

    def number(self, key, default=REQUIRED, positive=False, nonneg=False) -> float | None:
        """A real number: an int or a float (not a boolean, not quoted text), finite, at most MAX_MAGNITUDE.

        Args:
            key: the key read.
            default: the value of an absent or null key (None: optional, returned as None); REQUIRED: the
                key must be given.
            positive: refuse values that are not > 0.
            nonneg: refuse values < 0.

        Returns:
            float | None: the number as a float, or None for an absent optional key.

        Raises:
            ScenarioError: the value is missing, not a real number, not finite, too large, or out of sign.
        """
        v = self.raw(key, default)
        if v is None and default is None:   # optional key, absent
            return None
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.fail(key, f"expected a number, got {show_value(v)}")
        if isinstance(v, int) and abs(v) > MAX_MAGNITUDE:   # before float(): 10**400 overflows it
            self.fail(key, f"must be at most {MAX_MAGNITUDE:g} in magnitude, got {show_value(v, 24)}")
        v = float(v)
        if not np.isfinite(v):
            self.fail(key, f"must be finite, got {v}")
        if abs(v) > MAX_MAGNITUDE:
            self.fail(key, f"must be at most {MAX_MAGNITUDE:g} in magnitude, got {v:g}")
        if positive and not v > 0:
            self.fail(key, f"must be positive, got {v}")
        if nonneg and v < 0:
            self.fail(key, f"must be non-negative, got {v}")
        return v

    def whole(self, key, default=REQUIRED, positive=False, nonneg=False, maximum=None) -> int | None:
        """A whole number: an integer, or a float without a fractional part (10.0).

        10.5 is refused, never truncated; at most `maximum` when given.

        Args:
            key: the key read.
            default: the value of an absent or null key (None: optional, returned as None); REQUIRED: the
                key must be given.
            positive: refuse values that are not > 0.
            nonneg: refuse values < 0.
            maximum: the largest value accepted; None: MAX_MAGNITUDE only.

        Returns:
            int | None: the number, or None for an absent optional key.

        Raises:
            ScenarioError: the value is refused as by `number`, has a fractional part or exceeds `maximum`.
        """
        v = self.number(key, default, positive=positive, nonneg=nonneg)
        if v is None:
            return None
        if not v.is_integer():
            self.fail(key, f"must be a whole number, got {self.data.get(key, v)!r}")
        if maximum is not None and v > maximum:
            self.fail(key, f"must be at most {maximum:,}, got {v:g}")
        return int(v)

    def string(self, key, choices=None, default=REQUIRED) -> str:
        """A string, one of `choices` when given.

        Args:
            key: the key read.
            choices: the strings accepted; None: any string.
            default: the value of an absent or null key; REQUIRED: the key must be given.

        Returns:
            str: the string.

        Raises:
            ScenarioError: the value is missing, not a string, or not one of `choices`.
        """
        v = self.raw(key, default)
        if not isinstance(v, str):
            self.fail(key, f"expected a string, got {show_value(v)}")
        if choices is not None and v not in choices:
            self.fail(key, f"must be one of {', '.join(choices)}; got {show_value(v)}")
        return v

    def array(self, key, shape=None, default=REQUIRED, positive=False, nonneg=False, allow_inf=False) -> np.ndarray:
        """Numbers (nested lists) of `shape` (None: any length); every value a real number as in `number`.

        Args:
            key: the key read.
            shape: tuple of the expected dimensions, None in a dimension for any length there; None: a list
                of any length.
            default: the value of an absent or null key (trusted, not checked for numbers); REQUIRED: the
                key must be given.
            positive: refuse any value that is not > 0.
            nonneg: refuse any value < 0.
            allow_inf: +-inf allowed, e.g. "no limit" (nan never is).

        Returns:
            np.ndarray: float array of the given shape, in the units the field is given in.

        Raises:
            ScenarioError: a value is not a real number, the rows differ in length or the shape is wrong, a
                value is not finite (unless allowed), too large, or out of sign.
        """
        v = self.raw(key, default)
        if self.data.get(key) is not None:   # from the file (defaults are trusted)
            bad = _first_non_number(v)
            if bad is not _ALL_NUMBERS:
                self.fail(key, f"expected numbers, got {show_value(bad)}"
                          + ("" if bad is v else f" in {show_value(v)}"))
            big = _first_big_int(v)
            if big is not None:   # before float(): 10**400 overflows it
                self.fail(key, f"must be at most {MAX_MAGNITUDE:g} in magnitude, got {show_value(big, 24)}")
        try:
            a = np.array(v, dtype=float)
        except (TypeError, ValueError):
            want = "×".join("n" if s is None else str(s) for s in shape) if shape is not None else "n"
            self.fail(key, f"expected shape {want}, got rows of different lengths")
        if a.dtype == object or (shape is not None and (a.ndim != len(shape) or any(
                s is not None and s != d for s, d in zip(shape, a.shape)))):
            want = "×".join("n" if s is None else str(s) for s in shape)
            self.fail(key, f"expected shape {want}, got {list(a.shape)}")
        if np.any(np.isnan(a)) or (not allow_inf and not np.all(np.isfinite(a))):
            self.fail(key, "must be finite")
        finite = np.abs(a[np.isfinite(a)])
        if finite.size and finite.max() > MAX_MAGNITUDE:
            self.fail(key, f"must be at most {MAX_MAGNITUDE:g} in magnitude, got {finite.max():g}")
        if positive and not np.all(a > 0):
            self.fail(key, f"must be positive, got {a.tolist()}")
        if nonneg and not np.all(a >= 0):
            self.fail(key, f"must be non-negative, got {a.tolist()}")
        return a

    def rad_or_deg(self, key, shape, default=REQUIRED) -> np.ndarray:
        """Values under `key` (rad, or rad/s) or `key_deg` (deg, deg/s), in radians.

        Both keys at once are rejected.

        Args:
            key: the key in radians; `key_deg` is the same quantity in degrees.
            shape: the expected shape, as for `array`.
            default: the value when neither key is given (rad); REQUIRED: one of them must be given.

        Returns:
            np.ndarray: the values of `shape`, rad (or rad/s).

        Raises:
            ScenarioError: both keys are given, or the value is refused as by `array`.
        """
        deg = f"{key}_deg"
        if self.has(key) and self.has(deg):
            self.fail(key, f"give either {key} (rad) or {deg} (deg), not both")
        if self.has(deg):
            return np.deg2rad(self.array(deg, shape))
        return self.array(key, shape, default=default)

    def angles(self, key, shape, default=REQUIRED) -> np.ndarray:
        """Angles under `key` (rad) or `key_deg` (deg), in radians.

        Both keys at once, or rad values that look like degrees (|x| > 2π), are rejected.

        `rad_or_deg` is for quantities that are not angles, such as rates, which may exceed a turn (and
        the scenario reads joint coordinates with it, checking them against a turn by the joint's range,
        `coopsim.io.scenario`).

        Args:
            key: the key in radians; `key_deg` is the same angles in degrees.
            shape: the expected shape, as for `array`.
            default: the value when neither key is given (rad); REQUIRED: one of them must be given.

        Returns:
            np.ndarray: the values of `shape`, rad.

        Raises:
            ScenarioError: both keys are given, a value under `key` exceeds a turn, or the value is refused
                as by `array`.
        """
        deg = f"{key}_deg"
        a = self.rad_or_deg(key, shape, default)
        big = np.abs(a) > 2 * np.pi + 1e-9
        if not self.has(deg) and np.any(big):
            self.fail(key, f"{np.max(np.abs(a[big])):g} rad is more than a turn: degrees? use {deg}")
        return a

    def section(self, key, default=REQUIRED) -> "Section | None":
        """The nested mapping under `key` as a Section of its own (its path `path.key`).

        Args:
            key: the key read.
            default: the value of an absent or null key (None: optional, returned as None); REQUIRED: the
                key must be given.

        Returns:
            Section | None: the nested section, or None for an absent optional key.

        Raises:
            ScenarioError: the key is missing, or its value is not a mapping.
        """
        v = self.raw(key, default)
        return None if v is None else Section(v, self.field(key), self.where)

    def items(self, key, min_len=0) -> list["Section"]:
        """The list under `key`, each entry a Section of its own (its path `path.key[i]`).

        Args:
            key: the key read (required).
            min_len: the fewest entries accepted.

        Returns:
            list[Section]: one section per entry, in order.

        Raises:
            ScenarioError: the key is missing, not a list, shorter than `min_len`, or an entry is not a
                mapping.
        """
        v = self.raw(key)
        if not isinstance(v, list) or len(v) < min_len:
            self.fail(key, f"expected a list of at least {min_len} entries")
        return [Section(x, f"{self.field(key)}[{i}]", self.where) for i, x in enumerate(v)]

    def done(self):
        """Reject the keys of the mapping that no getter read (misspelt or unknown fields).

        Raises:
            ScenarioError: naming the first unknown key and the keys known here.
        """
        extra = sorted(set(self.data) - self.used, key=str)   # keys need not be strings (7:, null:)
        if extra:
            self.fail(show_value(extra[0]) if not isinstance(extra[0], str) else extra[0],
                      f"unknown field (known here: {', '.join(sorted(self.used))})")
