"""Record types mangled the same in every process. numba names a compiled function after its argument
types, a record type by its process-local type code (numba issue #7654: "Record mangling_args should not
use self._code"); a kernel cached on disk by one process then carries the symbol name another process gives
a different record, and linked together one calls the other's code: wrong numbers or a crash (seen here:
an estimator node reading another motor's state layout). Importing this module mangles record types by a
digest of their layout instead (numba's Record.key: every field's name, type and offset, and the size)."""
import hashlib

from numba.core import types


def _stable_mangling(record):
    return type(record).__name__, ("r" + hashlib.sha1(record.key.encode()).hexdigest(),)


types.Record.mangling_args = property(_stable_mangling)
