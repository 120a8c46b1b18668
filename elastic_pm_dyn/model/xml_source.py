"""XML model files (URDF, MJCF) read into :mod:`xml.etree` elements that know their line.

ElementTree drops line numbers; an error in a hand-edited or exported file must point at
the element. So the elements are built from expat's events here, with a map from element
to its line. Document type declarations are refused: a robot file needs no entities, and
refusing them rules out entity expansion ("billion laughs") whatever the expat version.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path
from xml.parsers import expat

from elastic_pm_dyn.errors import ModelError
from elastic_pm_dyn.text_file import TextFileError, read_head, read_text

MAX_XML_BYTES = 32 * 2**20  # exporters inline long visual lists; geometry stays in mesh files


class XmlSource:
    """The element tree of one XML file and the 1-based line of every element."""

    def __init__(self, text: str, file: str):
        self.file = file
        self.lines: dict[ET.Element, int] = {}
        builder = ET.TreeBuilder()
        parser = expat.ParserCreate()

        def start(tag: str, attrs: dict[str, str]) -> None:
            self.lines[builder.start(tag, attrs)] = parser.CurrentLineNumber

        def doctype(*_args) -> None:
            raise ModelError(file, "", "a DOCTYPE declaration is not accepted in a robot file",
                             parser.CurrentLineNumber)

        parser.StartElementHandler = start
        parser.EndElementHandler = builder.end
        parser.CharacterDataHandler = builder.data  # SDFormat writes its values as text
        parser.StartDoctypeDeclHandler = doctype
        try:
            parser.Parse(text, True)
        except expat.ExpatError as exc:
            raise ModelError(file, "", f"malformed XML: {expat.ErrorString(exc.code)}", exc.lineno) from None
        self.root: ET.Element = builder.close()

    @classmethod
    def from_file(cls, path: str | Path) -> XmlSource:
        try:
            text = read_text(path, MAX_XML_BYTES, "robot file")
        except TextFileError as exc:
            raise ModelError(str(path), "", exc.reason, exc.line) from None
        return cls(text, str(path))

    def line(self, element: ET.Element | None) -> int | None:
        return None if element is None else self.lines.get(element)

    def error(self, element: ET.Element | None, message: str, what: str | None = None) -> ModelError:
        """One line: ``file:line: <joint name="x">: message``."""
        return ModelError(self.file, what if what is not None else describe(element), message, self.line(element))


def describe(element: ET.Element | None) -> str:
    """``joint 'left_elbow'`` or ``inertial``: how a message names an element."""
    if element is None:
        return ""
    name = element.get("name")
    return f"{element.tag} {_short(name)}" if name is not None else element.tag


def _short(text: str, limit: int = 40) -> str:
    return repr(text if len(text) <= limit else text[:limit] + "...")


def is_xml(path: str | Path) -> str | None:
    """The root tag of an XML file (``robot``, ``mujoco``), or None for anything else."""
    try:
        head = read_head(path, 4096)  # a FIFO or device: None at once (its reader then refuses it)
    except TextFileError:
        return None
    text = head.decode("utf-8-sig", errors="replace").lstrip()
    if not text.startswith("<"):
        return None
    # skip the declaration and comments to the first element's name
    pos = 0
    while True:
        i = text.find("<", pos)
        if i < 0 or i + 1 >= len(text):
            return None
        if text.startswith("<?", i) or text.startswith("<!", i):
            end = text.find("-->", i) + 3 if text.startswith("<!--", i) else text.find(">", i) + 1
            if end <= 0:
                return None
            pos = end
            continue
        name = ""
        for ch in text[i + 1:]:
            if ch.isspace() or ch in "/>":
                break
            name += ch
        return name or None
