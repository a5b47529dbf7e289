"""How reports print a value in a table."""


def formatted(value, form):
    """``value`` in the format ``form``, or n/a where it is unknown (None)."""
    return "n/a" if value is None else form.format(value)


def cell(value):
    """A motor value as a table cell: a list of numbers, a text, or a number to 5 digits."""
    if isinstance(value, list):
        return " ".join(f"{v:.4g}" for v in value)
    return value if isinstance(value, str) else f"{value:.5g}"
