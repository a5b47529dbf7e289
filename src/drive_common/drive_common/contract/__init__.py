"""The drive interface contract (docs/drive-interface.md) as code: the topic table, the wire format, the log
layout, sample stamps, the estimator's records, exit codes, domain errors and the declared keys."""
