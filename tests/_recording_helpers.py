"""Shared helpers of the recording tests (reading columns back from a recording's chunks)."""


def column(batches, name):
    """All non-null values of a column over an entity's chunks (each log call is a row), in row order."""
    vals = []
    for b in batches:
        if name in b.schema.names:
            vals += [v for v in b.column(name).to_pylist() if v is not None]
    return vals
