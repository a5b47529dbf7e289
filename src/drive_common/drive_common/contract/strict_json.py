"""Strict JSON (RFC 8259: no NaN or Infinity) of the drive's data: parameter tuples become objects,
arrays lists, non-finite numbers null, anything else unknown its text. Every --json output, drive_config
and the files the tools write go through ``dumps``."""
import json
import math


def plain(value):
    """JSON-ready data with non-finite floats as None."""
    if hasattr(value, "_asdict"):
        return {k: plain(v) for k, v in value._asdict().items()}
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if hasattr(value, "tolist"):
        return plain(value.tolist())
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if value is None or isinstance(value, (bool, int, str)):
        return value
    return str(value)


def dumps(value, **kwargs):
    """Strict JSON text of ``value``."""
    return json.dumps(plain(value), allow_nan=False, **kwargs)
