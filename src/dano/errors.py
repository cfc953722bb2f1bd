"""Errors raised by dano. All derive from :class:`ValueError` so callers that
already catch bad input keep working; the CLI turns them into one-line messages
and a non-zero exit code."""


class DanoError(ValueError):
    """Bad input or an impossible request; the message names the file or argument."""


class FileFormatError(DanoError):
    """A file could not be read: wrong format, version, truncated or inconsistent."""


class DanoWarning(UserWarning):
    """Something dano did as asked but that is probably not what was meant (e.g. an object
    placed deep inside another body, :func:`dano.sim.rollout.deep_start_lines`)."""
