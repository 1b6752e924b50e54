"""umbra's exceptions: one base class, and two that are also the built-in exception a Python
caller already catches (``OSError`` for files, ``ValueError`` for arguments)."""


class Error(Exception):
    """Base class of every error umbra raises. ``str(e)`` is the message ``umbra`` prints
    after ``umbra: error:``."""


class FileError(Error, OSError):
    """A file could not be read or written: missing, unreadable, not a VDB file, corrupt, an
    unsupported feature, an output that exists or cannot be written."""


class InvalidArgument(Error, ValueError):
    """An argument is out of range, of the wrong shape or type, names a grid the file does not
    hold, or an estimator or parameter that does not exist."""
