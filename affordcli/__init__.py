"""`affordcli`: the `afford` command, the command-line face of affordmap. Each command parses its arguments
and calls the library (affordcore) or the services; the computing happens there. Heavy imports live inside
the commands, so `afford --help` is instant. The package is not called `afford`: that name belongs to the
Python that protoc generates from schemas/ (`afford.v1`), which is left to clients."""
