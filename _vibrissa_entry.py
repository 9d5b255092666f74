"""The ``vibrissa`` command's entry point, a module outside the ``vibrissa`` package: importing
the package loads numpy, scipy and numba (0.3-0.5 s), and a Ctrl-C meanwhile ends the command
with status 130 (128 + SIGINT) and no traceback, as it does once the command runs
(`vibrissa.cli.main`). It imports nothing before that, not even ``signal``."""


def main() -> int:
    """Run ``vibrissa`` with ``sys.argv``; its exit status."""
    try:
        from vibrissa.cli.main import main as command
    except KeyboardInterrupt:
        return 130
    return command()
