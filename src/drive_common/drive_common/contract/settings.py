"""Checks of configuration values: each returns the value in its Python type or raises ValueError
saying, in one line, what the key must be and what it was. The caller adds where it came from. Keys
are declared once (Key: unit, bounds, default) and read through ``read_keys``; files carry a format
version (``read_format_version``)."""
import difflib
import math
import reprlib
import sys
import warnings
from dataclasses import dataclass


def number(key, value, low=None, high=None, low_inclusive=False, high_inclusive=True, allow_infinite=False,
           integer=False):
    """A real number (an int when ``integer``) in the interval given by ``low``/``high`` (None: open)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (integer and not isinstance(value, int)):
        raise ValueError(f"{key}: must be {'a whole' if integer else 'a'} number, not {shown(value)}")
    if math.isnan(value) or (math.isinf(value) and not allow_infinite):
        raise ValueError(f"{key}: must be a finite number, not {shown(value)}")
    if math.isinf(value) and value > 0.0 and allow_infinite:
        return float(value)
    below = low is not None and (value < low if low_inclusive else value <= low)
    above = high is not None and (value > high if high_inclusive else value >= high)
    if (below or above) and high is None and low == 0:
        raise ValueError(f"{key}: must {'not be negative' if low_inclusive else 'be positive'}, not {shown(value)}")
    if (below or above) and integer and low_inclusive and high_inclusive and None not in (low, high):
        raise ValueError(f"{key}: must be a whole number from {int(low)} to {int(high)}, not {shown(value)}")
    if below or above:
        left = "[" if low_inclusive else "("
        right = "]" if high_inclusive else ")"
        interval = f"{left}{'−∞' if low is None else f'{low:g}'}, {'∞' if high is None else f'{high:g}'}{right}"
        raise ValueError(f"{key}: must lie in {interval}, not {shown(value)}")
    return int(value) if integer else float(value)


def positive(key, value, high=None, allow_infinite=False):
    """A number > 0 (and ≤ ``high``)."""
    return number(key, value, low=0.0, high=high, allow_infinite=allow_infinite)


def flag(key, value):
    """true or false."""
    if not isinstance(value, bool):
        raise ValueError(f"{key}: must be true or false, not {shown(value)}")
    return value


def choice(key, value, choices):
    """One of ``choices``."""
    if value not in choices:
        raise ValueError(f"{key}: must be one of {', '.join(map(str, choices))}, not {shown(value)}")
    return value


REQUIRED = object()
"""A Key's default when a file must give it."""


@dataclass(frozen=True)
class Key:
    """One configuration key, declared once (docs/architecture.md "Declared keys"): its unit, its bounds,
    whether it is whole, and its default (REQUIRED: none). Every file and node that reads the key reads it
    through ``read``."""

    name: str
    unit: str
    low: float = None
    high: float = None
    low_inclusive: bool = False
    high_inclusive: bool = True
    integer: bool = False
    default: object = REQUIRED
    doc: str = ""
    choices: tuple = ()
    """A key that is one of these (words, true/false) rather than a number."""
    infinite: bool = False
    """∞ is a value (e.g. "no limit")."""
    nullable: bool = False
    """null is a value (e.g. "the nameplate's"); otherwise a key is given a value or left out."""

    def read(self, value):
        """The value as its Python type (an int when ``integer``; a whole float is taken); ValueError in one
        line naming the key, the value and the bound."""
        if self.choices:
            if not any(value is c or (type(value) is type(c) and value == c) for c in self.choices):
                raise ValueError(f"{self.name}: must be {self.bounds()}, not {shown(value)}")
            return value
        if self.integer and isinstance(value, float) and value.is_integer():
            value = int(value)
        try:
            return number(self.name, value, self.low, self.high, self.low_inclusive, self.high_inclusive,
                          allow_infinite=self.infinite, integer=self.integer)
        except ValueError as error:
            raise ValueError(f"{error}{f' [{self.unit}]' if self.unit else ''}") from None

    def bounds(self):
        """The key's interval as text, e.g. "(0, 1e+04] A", or its choices ("one of step, linear", "true or
        false")."""
        if self.choices == (True, False):
            return "true or false"
        if self.choices:
            return f"one of {', '.join(map(str, self.choices))}"
        left, right = "[" if self.low_inclusive else "(", "]" if self.high_inclusive else ")"
        low = "−∞" if self.low is None else f"{self.low:g}"
        high = "∞" if self.high is None else f"{self.high:g}"
        return f"{left}{low}, {high}{right}{f' {self.unit}' if self.unit else ''}"


def refuse_unknown_keys(data, known, prefix=""):
    """ValueError in one line naming the first key of the mapping ``data`` not in ``known`` (after
    ``prefix``) and the nearest known one (a typo), else the known ones."""
    if not isinstance(data, dict):
        raise ValueError(f"{prefix.rstrip('.') or 'top level'}: must be a mapping of keys, not {shown(data)}")
    known = list(known)
    for name in sorted(set(data) - set(known), key=str):
        near = difflib.get_close_matches(str(name), known, n=1)
        hint = f"did you mean {near[0]}?" if near else f"known: {', '.join(known)}"
        raise ValueError(f"{prefix}{name}: unknown key ({hint})")


def read_keys(data, keys, prefix="", known_extra=()):
    """{name: value} of the mapping ``data`` read through the declared ``keys`` (a tuple of Key), defaults
    filled (a key whose default is None stays None when absent). ValueError in one line naming the key
    (after ``prefix``): an unknown key (refuse_unknown_keys), a missing required one, or a value out of its
    declaration. ``known_extra``: other keys the caller reads itself."""
    refuse_unknown_keys(data, [key.name for key in keys] + list(known_extra), prefix)
    values = {}
    for key in keys:
        if key.name not in data:
            if key.default is REQUIRED:
                raise ValueError(f"{prefix}{key.name}: missing ({key.doc or key.bounds()})")
            values[key.name] = key.default
            continue
        if data[key.name] is None and key.nullable:
            values[key.name] = None
            continue
        try:
            values[key.name] = key.read(data[key.name])
        except ValueError as error:
            raise ValueError(f"{prefix}{error}") from None
    return values


def read_or_fail(fail, read, *args, **kwargs):
    """``read(*args, **kwargs)`` (read_keys, a Key's read, ``number``...); its ValueError "KEY: problem"
    goes to ``fail(key, problem)``, which raises the reader's own error naming its file."""
    try:
        return read(*args, **kwargs)
    except ValueError as error:
        key, problem = str(error).split(": ", 1)
        fail(key, problem)


FORMAT_VERSION_KEY = "format_version"
"""The key of a file's format version (motor, drive configuration and commissioning files; a scenario file may
state its drive part's)."""


class FormatMigrated(UserWarning):
    """A file of an older format was read as the current one (one line: the file, its version, what was
    done)."""


def read_format_version(data, current, what, source):
    """The format version of the document ``data`` (a mapping) of a file of kind ``what``, whose current
    format is ``current``: one without the key is format 0 (written before formats were versioned) and,
    like any older one, is read as the current with a FormatMigrated warning; ValueError in one line for
    a version not a whole number, or newer than ``current``. ``source`` names the file in the warning."""
    version = data.get(FORMAT_VERSION_KEY, 0)
    if isinstance(version, bool) or not isinstance(version, int) or version < 0:
        raise ValueError(f"{FORMAT_VERSION_KEY}: must be a whole number (this drive writes {current}), "
                         f"not {shown(version)}")
    if version > current:
        raise ValueError(f"{FORMAT_VERSION_KEY}: {version}: a {what} of a newer format than this drive reads "
                         f"(up to {current}); update the drive")
    if version < current:
        written = "without format_version" if version == 0 else f"of format {version}"
        warnings.warn(f"{source}: a {what} {written}, read as format {current} (nothing in it changed meaning; add "
                      f"`{FORMAT_VERSION_KEY}: {current}`)", FormatMigrated, stacklevel=2)
    return version


def show_warnings_in_one_line(program):
    """Print FormatMigrated warnings as one line on stderr, "PROGRAM: warning: …" (others as Python does)."""
    original = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, FormatMigrated):
            print(f"{program}: warning: {message}", file=sys.stderr if file is None else file)
        else:
            original(message, category, filename, lineno, file, line)
    warnings.showwarning = show


_SHORT = reprlib.Repr()
_SHORT.maxlevel, _SHORT.maxlist, _SHORT.maxdict, _SHORT.maxtuple = 2, 4, 4, 4
_SHORT.maxstring = _SHORT.maxother = _SHORT.maxlong = 60


def shown(value):
    """A value as an error line quotes it: its repr, shortened past 60 characters and two levels of nesting
    (a YAML alias can make a value of gigabytes)."""
    return _SHORT.repr(value)
