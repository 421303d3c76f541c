"""What every console script does with a user error: one line on stderr, exit code 1.

Unexpected internal errors keep their traceback; only the project's own errors (and the config
errors an entry point names) count as the user's. Hydra wraps errors raised while instantiating an
object, so the whole ``__cause__`` / ``__context__`` chain is searched.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager

from uss_slam.core.errors import UssSlamError


def user_error(
    error: BaseException | None, kinds: tuple[type[BaseException], ...] = ()
) -> BaseException | None:
    """The first error in ``error``'s cause chain that is a user error, else None."""
    accepted = (UssSlamError, *kinds)
    seen: set[int] = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, accepted):
            return error
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return None


def error_line(prog: str, error: BaseException) -> str:
    """``"<prog>: error: <first line of the message>"``."""
    text = str(error).strip() or type(error).__name__
    return f"{prog}: error: {text.splitlines()[0]}"


@contextmanager
def exit_on_user_error(prog: str, kinds: tuple[type[BaseException], ...] = ()) -> Iterator[None]:
    """Run the body; a user error anywhere in the cause chain becomes one line and exit code 1.

    ``kinds`` adds exception types the entry point treats as user errors (Hydra apps pass
    OmegaConf's config errors). Anything else propagates with its traceback.
    """
    try:
        yield
    except (KeyboardInterrupt, SystemExit):
        raise
    except BaseException as error:
        cause = user_error(error, kinds)
        if cause is None:
            raise
        print(error_line(prog, cause), file=sys.stderr)
        sys.exit(1)
