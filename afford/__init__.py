"""`afford`: the command-line face of affordmap. Each command parses its arguments and calls the library
(affordcore) or the services; the computing happens there. Heavy imports live inside the commands, so
`afford --help` is instant."""
