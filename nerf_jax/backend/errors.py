"""One-line errors for every command line (nerf-train, nerf-render, nerf-view, nerf-process, the
benchmark): an error the user can fix is printed as one line `error: ...` and exits with status 1;
`--verbosity=1` (absl) shows the full traceback instead.

In the lowest layer so that a command of any layer (data/process.py's nerf-process, cli.py's)
shares it; each command names the exceptions whose message is the whole story for its user.
"""

import contextlib
import sys

from absl import flags, logging


def wants_traceback(argv):
  """Whether argv (the command line, program name first) sets --verbosity (or -v)."""
  return any(a.lstrip("-").split("=")[0] in ("verbosity", "v") for a in argv[1:])


def fail(message):
  """Print `error: message` on stderr and exit with status 1."""
  print(f"error: {message}", file=sys.stderr)
  sys.exit(1)


def parse_flags(argv, flag_values=flags.FLAGS):
  """`app.run`'s flags_parser: a bad flag or override exits 1 with one line.

  Returns the positional arguments; refuses any (every setting is a flag).
  """
  try:
    rest = flag_values(argv)
  except flags.Error as e:
    if wants_traceback(argv):
      raise
    lines = [l.strip() for l in str(e).splitlines() if l.strip()] or [type(e).__name__]
    fail(lines[0] if len(lines) == 1 else f"{lines[0]} {lines[-1]}")
  if len(rest) > 1:
    fail(f"unexpected argument {rest[1]!r}: settings are flags, e.g. --config.data.path=...")
  return rest


def run_main(fn, user_errors=(FileNotFoundError, ValueError)):
  """Run fn() for its effects under `one_line_errors(user_errors)`."""
  with one_line_errors(user_errors):
    fn()


@contextlib.contextmanager
def one_line_errors(user_errors=(FileNotFoundError, ValueError)):
  """Around a command's work: turn `user_errors` (a tuple of exception classes whose message is
  the whole story for the user) into one line on stderr and exit status 1, an interrupt into
  exit status 130."""
  if not flags.FLAGS["verbosity"].present:
    logging.set_verbosity(logging.WARNING)  # hide JAX's backend-probing INFO lines by default
  try:
    yield
  except KeyboardInterrupt as e:
    print(f"interrupted: {e}" if str(e) else "interrupted", file=sys.stderr)
    sys.exit(130)
  except user_errors as e:
    if logging.get_verbosity() >= logging.DEBUG:
      raise
    print(f"error: {e}", file=sys.stderr)
    sys.exit(1)
