"""The drawn-instance generator: every effect family at a joint, size, timing and law's shape drawn per seed.

It writes campaigns in the blind-campaign format (``docs/formats.md``, "Blind campaigns") with their answer keys. It
imports no part of the diagnosis (nor anything that imports it): from the library only :mod:`twin.units`.
"""
