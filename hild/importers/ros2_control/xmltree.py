"""XML with line numbers, and a writer that puts every element back on its line.

The standard library's ElementTree forgets where an element was; the importer must point at lines, and the twin's
copy of the URDF must keep them (so a report line is right for the copy too). expat gives both: each node keeps
the line it started on, and :func:`serialize` pads with newlines so no node lands above its original line.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from xml.parsers import expat
from xml.sax.saxutils import escape, quoteattr


class XmlSyntaxError(ValueError):
    def __init__(self, line: int, message: str) -> None:
        self.line = line
        super().__init__(message)


@dataclass
class XmlText:
    text: str
    line: int


@dataclass
class XmlComment:
    text: str
    line: int


@dataclass
class XmlElement:
    tag: str
    attrib: dict[str, str]
    line: int
    children: list[XmlElement | XmlText | XmlComment] = field(default_factory=list)

    def elements(self, tag: str | None = None) -> Iterator[XmlElement]:
        """Direct child elements, optionally only those named ``tag``."""
        for child in self.children:
            if isinstance(child, XmlElement) and (tag is None or child.tag == tag):
                yield child

    def find(self, tag: str) -> XmlElement | None:
        return next(self.elements(tag), None)

    def iter(self, tag: str | None = None) -> Iterator[XmlElement]:
        """This element and every descendant, in document order."""
        if tag is None or self.tag == tag:
            yield self
        for child in self.elements():
            yield from child.iter(tag)

    @property
    def text(self) -> str:
        """The element's own text, stripped."""
        return "".join(c.text for c in self.children if isinstance(c, XmlText)).strip()


@dataclass
class XmlDocument:
    root: XmlElement
    declaration: str | None = None  # the <?xml ...?> line, when the source had one
    prolog: list[XmlComment] = field(default_factory=list)  # comments before the root element


def parse_xml(text: str) -> XmlDocument:
    """Parse ``text``; a malformed document raises :class:`XmlSyntaxError` with expat's line and message."""
    parser = expat.ParserCreate()
    stack: list[XmlElement] = []
    roots: list[XmlElement] = []
    declaration: list[str] = []
    prolog: list[XmlComment] = []

    def start(tag: str, attrib: dict[str, str]) -> None:
        element = XmlElement(tag, dict(attrib), parser.CurrentLineNumber)
        if stack:
            stack[-1].children.append(element)
        else:
            roots.append(element)
        stack.append(element)

    def end(tag: str) -> None:
        stack.pop()

    def data(chunk: str) -> None:
        if not stack:
            return
        children = stack[-1].children
        if children and isinstance(children[-1], XmlText):
            children[-1].text += chunk  # expat splits text at newlines and entities
        else:
            children.append(XmlText(chunk, parser.CurrentLineNumber))

    def comment(chunk: str) -> None:
        node = XmlComment(chunk, parser.CurrentLineNumber)
        if stack:
            stack[-1].children.append(node)
        elif not roots:
            prolog.append(node)

    def xml_decl(version: str, encoding: str | None, standalone: int) -> None:
        declaration.append(f'<?xml version="{version}"?>')

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CharacterDataHandler = data
    parser.CommentHandler = comment
    parser.XmlDeclHandler = xml_decl
    try:
        parser.Parse(text, True)
    except expat.ExpatError as exc:
        raise XmlSyntaxError(exc.lineno, f"not well-formed XML: {expat.errors.messages[exc.code]}") from None
    return XmlDocument(roots[0], declaration[0] if declaration else None, prolog)


def serialize(document: XmlDocument) -> str:
    """XML text in which every node starts on the line it was parsed from (added nodes: on their given line)."""
    out: list[str] = []
    line = 1

    def put(text: str) -> None:
        nonlocal line
        out.append(text)
        line += text.count("\n")

    def pad_to(target: int) -> None:
        if target > line:
            put("\n" * (target - line))

    def write(node: XmlElement | XmlText | XmlComment) -> None:
        pad_to(node.line)
        if isinstance(node, XmlText):
            put(escape(node.text))
        elif isinstance(node, XmlComment):
            put(f"<!--{node.text}-->")
        else:
            attrs = "".join(f" {name}={quoteattr(value)}" for name, value in node.attrib.items())
            if not node.children:
                put(f"<{node.tag}{attrs}/>")
                return
            put(f"<{node.tag}{attrs}>")
            for child in node.children:
                write(child)
            put(f"</{node.tag}>")

    if document.declaration:
        put(document.declaration)
    for node in document.prolog:
        write(node)
    write(document.root)
    put("\n")
    return "".join(out)
