"""Reading XML with each element's file and line (tree files, palettes)."""

from __future__ import annotations

import xml.etree.ElementTree as ET
import xml.parsers.expat
from pathlib import Path

from canguard.errors import TreeError

Where = tuple[Path, int]


def _read_xml(path: Path, where: dict[ET.Element, Where]) -> ET.Element:
    """Parse ``path`` with expat, recording each element's (file, line) in ``where``."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise TreeError(f"{path}: cannot read the tree file: {exc.strerror or exc}") from None
    builder = ET.TreeBuilder()
    parser = xml.parsers.expat.ParserCreate()

    def start(tag: str, attrs: dict[str, str]) -> None:
        where[builder.start(tag, attrs)] = (path, parser.CurrentLineNumber)

    parser.StartElementHandler = start
    parser.EndElementHandler = builder.end
    try:
        parser.Parse(data, True)
    except xml.parsers.expat.ExpatError as exc:
        msg = xml.parsers.expat.ErrorString(exc.code)
        raise TreeError(f"{path}:{exc.lineno}: not well-formed XML: {msg} (column {exc.offset + 1})") from None
    return builder.close()


