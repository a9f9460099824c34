"""JSON with comments, as jsoncpp (ARCSim's JSON reader) accepts it: ``//`` to the end of the line
and ``/* ... */``, outside strings. Used by the ARCSim configuration reader (cloth.io.arcsim), its
output reader (cloth.io.arcsim_output) and the measured-material reader (cloth.core.measured)."""

from __future__ import annotations


def strip_json_comments(text: str) -> str:
    """`text` with every ``//`` and ``/* */`` comment outside strings replaced by spaces (newlines
    kept), so the result has the same length, lines and columns. A ``/*`` without its ``*/``
    raises ValueError naming the line and column where it starts."""
    out = list(text)
    i, n = 0, len(text)
    in_string = False
    while i < n:
        c = text[i]
        if in_string:
            if c == "\\":
                i += 2  # an escape: the next character cannot end the string
                continue
            if c == '"':
                in_string = False
        elif c == '"':
            in_string = True
        elif c == "/" and i + 1 < n and text[i + 1] == "/":
            while i < n and text[i] != "\n":
                out[i] = " "
                i += 1
            continue
        elif c == "/" and i + 1 < n and text[i + 1] == "*":
            end = text.find("*/", i + 2)
            if end < 0:
                line = text.count("\n", 0, i) + 1
                col = i - (text.rfind("\n", 0, i) + 1) + 1
                raise ValueError(f"line {line} column {col}: a /* comment is never closed")
            for j in range(i, end + 2):
                if text[j] != "\n":
                    out[j] = " "
            i = end + 2
            continue
        i += 1
    return "".join(out)
