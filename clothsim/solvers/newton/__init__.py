"""Active-set Newton (transitional: the module moved to this package; split by job next)."""

from . import linalg as _impl

globals().update({k: v for k, v in vars(_impl).items() if not k.startswith("__")})
