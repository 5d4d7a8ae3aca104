"""User text in generated files, safe by construction: one function per target, used by every writer.

A system file's description, its path, its sources and names reach the C headers of ``export-c``,
the FMU's ``modelDescription.xml`` and the READMEs. None of them may change what the generated file
*is*: text inside a C comment must stay inside it (``*/``, and a backslash-newline, which the C
preprocessor splices before it removes comments, would end it early; so would a trigraph ``??/``
under ``-std=c89``/``-trigraphs``), a C string literal must stay one literal, an XML attribute must be
well-formed XML 1.0 (which has no representation at all for most control characters), and a word of
a Makefile or a CMake file must be one plain word.

:func:`visible` is the first step of every target: characters that are not printable (control and
format characters, among them the bidirectional overrides of "Trojan Source", CVE-2021-42574, line
and paragraph separators, surrogates, unassigned code points) become the seven visible characters
``<U+XXXX>``; a newline is kept only where the target allows several lines. Then each target escapes
what its own syntax gives meaning to:

* :func:`c_comment` (one line inside ``/* */``): ``\\`` becomes ``<U+005C>`` (no line splice can
  exist), a space is put between ``*`` and ``/``, ``/`` and ``*``, and ``?`` and ``?`` (no comment end,
  no nested-comment warning, no trigraph);
* :func:`c_comment_lines`: several such lines, split at newlines;
* :func:`c_string`: a C string literal (quotes included) whose bytes are the UTF-8 of the visible
  text: printable ASCII as itself except ``\\``, ``"`` and ``?`` (escaped), a newline as ``\\n``,
  every other byte as a three-digit octal escape (octal escapes stop after three digits, hex ones do not);
* :func:`xml_attr`: a quoted XML attribute value (``&``, ``<``, ``>``, ``"``, tab, newline and
  carriage return as character references);
* :func:`markdown`: one line of Markdown text (backticks become ``'``);
* :func:`build_word`: refuses (``ValueError``, one line) a Makefile/CMake word that is not a plain
  ``[A-Za-z0-9_.+=/,-]`` word: those files carry no user text, only names arvcas validated, and this
  is their last check.
"""

from __future__ import annotations

import re
from xml.sax.saxutils import quoteattr

__all__ = ["visible", "c_comment", "c_comment_lines", "c_string", "xml_attr", "markdown", "build_word"]


def _mark(c: str) -> str:
    return f"<U+{ord(c):04X}>"


def visible(text, newlines: bool = False) -> str:
    """``text`` (anything: ``str()`` is taken) with every non-printable character as ``<U+XXXX>``;
    with ``newlines``, ``\\r\\n``, ``\\r`` and ``\\n`` become one ``\\n`` and are kept."""
    s = str(text)
    if newlines:
        s = s.replace("\r\n", "\n").replace("\r", "\n")
    return "".join(c if c.isprintable() or (newlines and c == "\n") else _mark(c) for c in s)


def c_comment(text) -> str:
    """One line of text to put inside a C or C++ ``/* ... */`` comment (newlines shown as <U+000A>)."""
    s = visible(text).replace("\\", _mark("\\"))
    s = re.sub(r"\*(?=/)", "* ", s)
    s = re.sub(r"/(?=\*)", "/ ", s)
    return re.sub(r"\?(?=\?)", "? ", s)


def c_comment_lines(text) -> list[str]:
    """The lines of ``text`` (split at its newlines), each made safe by :func:`c_comment`."""
    return [c_comment(line) for line in visible(text, newlines=True).split("\n")]


def c_string(text) -> str:
    """A C (and C++) string literal, quotes included, of the UTF-8 bytes of :func:`visible` ``(text)``."""
    out = []
    for b in visible(text, newlines=True).encode("utf-8"):
        c = chr(b)
        if c in '\\"?':
            out.append("\\" + c)
        elif c == "\n":
            out.append("\\n")
        elif 0x20 <= b < 0x7F:
            out.append(c)
        else:
            out.append(f"\\{b:03o}")
    return '"' + "".join(out) + '"'


def xml_attr(text) -> str:
    """A quoted XML 1.0 attribute value (quotes included) of ``text``, newlines kept as references."""
    return quoteattr(visible(text, newlines=True))  # quoteattr writes \n, \r, \t as &#10; &#13; &#9;


def markdown(text) -> str:
    """One line of Markdown text: :func:`visible`, backticks as ``'``."""
    return visible(text).replace("`", "'")


_WORD = re.compile(r"[A-Za-z0-9_.+=/,-]+")


def build_word(word, what: str) -> str:
    """``word`` if it is one plain word for a Makefile or a CMake file, else ValueError naming ``what``."""
    if not isinstance(word, str) or not _WORD.fullmatch(word):
        raise ValueError(f"{what}: {visible(word)!r} is not a plain word (allowed: letters, digits, _ . + = / , -)")
    return word
