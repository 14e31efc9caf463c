"""One root for the errors footmesh raises on purpose, and the rule for what is whose fault.

    FootmeshError
    +-- InputError     the user's file or flags are wrong (a corrupt photo, depth in the wrong unit, --port 0)
    +-- Refusal        the photo is readable but cannot be measured (no foot, cut off, end-on); says what to retake
    +-- InternalError  footmesh itself failed (shown as such, never blamed on the input)

The rule, applied by the CLI, the batch runner and the web server alike (``is_users_fault``): an ``InputError``
or a ``Refusal`` is the user's, and is told in one line; **anything else** -- a bare ``ValueError`` from inside a
stage, ``numpy.linalg.LinAlgError``, a shipped file gone missing -- is footmesh's, reported as an internal error
with its traceback written to a log file. Stages therefore raise ``InputError`` / ``Refusal`` where the input is
to blame and plain ``ValueError`` for broken internal contracts. (The developer commands -- model, synth, train,
eval -- read the developer's own folders and JSON configurations, and report their ``ValueError`` and
``FileNotFoundError`` as input errors: ``footmesh.cli``.)

``InputError`` and ``Refusal`` are also ``ValueError``s, so code that validates arguments with
``pytest.raises(ValueError)`` or ``except ValueError`` keeps working.
"""

from __future__ import annotations

import sys
import tempfile
import traceback


class FootmeshError(Exception):
    """Root of the errors footmesh raises on purpose."""


class InputError(FootmeshError, ValueError):
    """The user's file or flags cannot be used; the message is one sentence naming the input and the fix."""


class Refusal(FootmeshError, ValueError):
    """The photo cannot be measured; ``why`` is the evidence, ``retake`` what to photograph instead (or None)."""

    def __init__(self, why: str, retake: str | None = None) -> None:
        self.why = why
        self.retake = retake
        super().__init__(why if retake is None else f"{why}; {retake}")

    def __reduce__(self):  # picklable with both fields (the web's measuring processes send refusals back)
        return (type(self), (self.why, self.retake))


class InternalError(FootmeshError, RuntimeError):
    """A fault of footmesh itself that it detects (a NaN about to be written, a result of the wrong type);
    reported as internal, never as the user's. Any exception not listed above is treated the same."""


def is_users_fault(exc: BaseException) -> bool:
    """True for the errors the user can fix (``InputError``, ``Refusal``), False for footmesh's own."""
    return isinstance(exc, InputError | Refusal)


def one_line(exc: BaseException) -> str:
    """The message of ``exc`` on one line (its type where it has none)."""
    text = " ".join(str(exc).split())
    return text if text else type(exc).__name__


def write_internal_report(exc: BaseException, version: str) -> str:
    """Write the traceback of ``exc`` to a log file; returns the one-line report that names the file."""
    with tempfile.NamedTemporaryFile("w", prefix="footmesh-internal-", suffix=".log", delete=False) as f:
        f.write(f"footmesh {version}: {' '.join(sys.argv)}\n")
        f.write("".join(traceback.format_exception(exc)))
    summary = f"{type(exc).__name__}: {one_line(exc)}"[:200] if str(exc).strip() else type(exc).__name__
    return f"internal error (a fault of footmesh, not of your input): {summary}; details in {f.name}"
