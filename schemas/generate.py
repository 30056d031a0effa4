"""Generate the Python message classes in affordwire/proto/ from schemas/afford/v1/*.proto.

    python schemas/generate.py            # rewrite affordwire/proto/*_pb2.py(i)
    python schemas/generate.py --check    # exit 1 if the checked-in code is stale (what the tests run)

Needs grpcio-tools (a test dependency), which bundles protoc. The generated modules import each other as
``afford.v1.<name>_pb2``; they are rewritten to relative imports so they live inside the affordwire package.
"""

from __future__ import annotations

import re
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SCHEMAS = ROOT / "schemas"
PACKAGE = ROOT / "affordwire" / "proto"
_ABSOLUTE_IMPORT = re.compile(r"^from afford\.v1 import (\w+_pb2)", re.MULTILINE)


def generate() -> dict[str, str]:
    """{file name: generated text} for every .proto under schemas/afford/v1."""
    import grpc_tools
    from grpc_tools import protoc

    protos = sorted(str(p.relative_to(SCHEMAS)) for p in (SCHEMAS / "afford" / "v1").glob("*.proto"))
    well_known = Path(grpc_tools.__file__).parent / "_proto"
    with tempfile.TemporaryDirectory() as out:
        status = protoc.main(
            ["protoc", f"-I{SCHEMAS}", f"-I{well_known}", f"--python_out={out}", f"--pyi_out={out}", *protos]
        )
        if status != 0:
            raise SystemExit(f"protoc failed ({status}) on {protos}")
        generated = sorted((Path(out) / "afford" / "v1").glob("*_pb2.py*"))
        return {path.name: _ABSOLUTE_IMPORT.sub(r"from . import \1", path.read_text()) for path in generated}


def stale(files: dict[str, str]) -> list[str]:
    """Names of generated files that differ from (or are missing in, or are extra in) affordwire/proto."""
    present = {path.name for path in PACKAGE.glob("*_pb2.py*")}
    differ = [
        name
        for name, text in files.items()
        if not (PACKAGE / name).exists() or (PACKAGE / name).read_text() != text
    ]
    return sorted(differ + list(present - set(files)))


def main() -> int:
    files = generate()
    if "--check" in sys.argv:
        names = stale(files)
        if names:
            print(
                f"stale generated code: {', '.join(names)}; run: python schemas/generate.py", file=sys.stderr
            )
        return int(bool(names))
    for path in PACKAGE.glob("*_pb2.py*"):
        path.unlink()
    for name, text in files.items():
        (PACKAGE / name).write_text(text)
    print(f"wrote {len(files)} files to {PACKAGE.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
