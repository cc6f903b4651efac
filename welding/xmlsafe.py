"""A small, safe XML reader: elements with their line and column, nothing else.

It uses the standard library's expat directly, configured so that a hostile file can do
nothing but be refused: any DOCTYPE is an error (so no internal or external entity can be
declared, which stops "billion laughs" and XXE before they start), parameter entities are
never parsed, external entity references are refused, and the input size is bounded. No
network and no file besides the one given is ever opened. The standard library was chosen
over ``defusedxml`` because a job file needs no DTD at all, so refusing every DOCTYPE is
both simpler and stricter than defusing one, and the welding package then needs no extra
dependency.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from xml.parsers import expat

__all__ = ["MAX_BYTES", "MAX_DEPTH", "Element", "XmlRefused", "parse"]

#: Largest XML document accepted (bytes): a job with thousands of points is well below.
MAX_BYTES = 8 * 1024 * 1024
#: Deepest element nesting accepted: a job is four levels deep; the bound keeps every
#: recursive walk of the tree (checks, the console's rendering) far from Python's limit.
MAX_DEPTH = 32


class XmlRefused(ValueError):
    """The document is not well-formed or uses a refused construct; ``line``/``column``
    (1-based) locate it."""

    def __init__(self, message: str, line: int, column: int) -> None:
        super().__init__(f"{line}:{column}: {message}")
        self.message = message
        self.line = line
        self.column = column


@dataclass
class Element:
    """One element: tag, attributes in document order, children, text, position (1-based)."""

    tag: str
    attrs: dict[str, str]
    line: int
    column: int
    children: list[Element] = field(default_factory=list)
    text: str = ""


class _Refuse(Exception):
    def __init__(self, message: str) -> None:
        self.message = message


def parse(data: bytes) -> Element:
    """Parse ``data`` into an :class:`Element` tree; :class:`XmlRefused` otherwise."""
    if len(data) > MAX_BYTES:
        raise XmlRefused(f"file larger than {MAX_BYTES} bytes", 1, 1)
    parser = expat.ParserCreate()
    parser.SetParamEntityParsing(expat.XML_PARAM_ENTITY_PARSING_NEVER)
    stack: list[Element] = []
    root: list[Element] = []

    def refuse(what: str) -> None:
        raise _Refuse(what)

    def start(tag: str, attrs: dict[str, str]) -> None:
        if len(stack) >= MAX_DEPTH:
            refuse(f"elements nested deeper than {MAX_DEPTH} levels")
        el = Element(tag, dict(attrs), parser.CurrentLineNumber, parser.CurrentColumnNumber + 1)
        if stack:
            stack[-1].children.append(el)
        else:
            root.append(el)
        stack.append(el)

    def end(tag: str) -> None:
        stack.pop()

    def chars(text: str) -> None:
        if stack:
            stack[-1].text += text

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CharacterDataHandler = chars
    parser.StartDoctypeDeclHandler = lambda *a: refuse("DOCTYPE is not allowed (no DTDs)")
    parser.EntityDeclHandler = lambda *a: refuse("entity declarations are not allowed")
    parser.UnparsedEntityDeclHandler = lambda *a: refuse("entity declarations are not allowed")

    def external(*args: object) -> int:
        raise _Refuse("external entities are not allowed")

    parser.ExternalEntityRefHandler = external
    parser.SkippedEntityHandler = lambda *a: refuse("entity references are not allowed")
    try:
        parser.Parse(data, True)
    except _Refuse as exc:
        raise XmlRefused(
            exc.message, parser.CurrentLineNumber, parser.CurrentColumnNumber + 1
        ) from None
    except expat.ExpatError as exc:
        message = expat.ErrorString(exc.code) if exc.code is not None else str(exc)
        raise XmlRefused(f"not well-formed XML: {message}", exc.lineno, exc.offset + 1) from None
    return root[0]
