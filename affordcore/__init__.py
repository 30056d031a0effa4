"""affordmap's algorithm: geometry, learning, mapping and the generated training rooms (no transport, no wire
format, no command line)."""


def version() -> str:
    """The installed affordmap's version (CHANGELOG.md), or "unknown" in a source tree never installed."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as package_version

    try:
        return package_version("affordmap")
    except PackageNotFoundError:
        return "unknown"
