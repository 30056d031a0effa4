"""`python -m affordcli`: the `afford` command with this interpreter."""

from .app import app

if __name__ == "__main__":
    app()
