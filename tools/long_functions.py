#!/usr/bin/env python3
"""List every Rust `fn` whose body is longer than a limit (default 150 lines).

Usage: tools/long_functions.py [--limit N] [PATH ...]   (default PATH: crates)

A function's length is counted from the line of its `fn` keyword to the line of the brace
that closes its body. Braces are matched on the source with comments, string literals
(plain, byte and raw), and character literals blanked out, so braces inside them do not
count. Declarations without a body (trait methods ending in `;`) are skipped. Prints
`file:line  length  name`, longest first, and exits 0.
"""

import argparse
import os
import re
import sys

FN = re.compile(r"\bfn\s+([A-Za-z_][A-Za-z0-9_]*)")


def blank(src):
    """`src` with comments, strings and char literals replaced by spaces (newlines kept)."""
    out = []
    i, n = 0, len(src)

    def keep_newlines(s):
        return "".join(c if c == "\n" else " " for c in s)

    while i < n:
        c = src[i]
        if src.startswith("//", i):
            j = src.find("\n", i)
            j = n if j < 0 else j
            out.append(keep_newlines(src[i:j]))
            i = j
        elif src.startswith("/*", i):
            depth, j = 1, i + 2
            while j < n and depth:
                if src.startswith("/*", j):
                    depth, j = depth + 1, j + 2
                elif src.startswith("*/", j):
                    depth, j = depth - 1, j + 2
                else:
                    j += 1
            out.append(keep_newlines(src[i:j]))
            i = j
        elif re.match(r'b?r#*"', src[i:i + 40]) and not (i > 0 and (src[i - 1].isalnum() or src[i - 1] == "_")):
            m = re.match(r'(b?r)(#*)"', src[i:])
            end = '"' + m.group(2)
            j = src.find(end, i + len(m.group(0)))
            j = n if j < 0 else j + len(end)
            out.append(keep_newlines(src[i:j]))
            i = j
        elif c == '"' or (c == "b" and src.startswith('b"', i) and not (i > 0 and (src[i - 1].isalnum() or src[i - 1] == "_"))):
            j = i + (2 if c == "b" else 1)
            while j < n and src[j] != '"':
                j += 2 if src[j] == "\\" else 1
            j += 1
            out.append(keep_newlines(src[i:j]))
            i = j
        elif c == "'":
            # A char literal ('x', '\n', '\u{..}', '{'), not a lifetime ('a).
            m = re.match(r"'(\\u\{[0-9a-fA-F]+\}|\\.|[^\\'])'", src[i:])
            if m:
                out.append(" " * len(m.group(0)))
                i += len(m.group(0))
            else:
                out.append(c)
                i += 1
        else:
            out.append(c)
            i += 1
    return "".join(out)


def functions(path):
    """(line, length, name) of every fn with a body in the file."""
    src = blank(open(path, encoding="utf-8").read())
    line_of = []
    ln = 1
    for ch in src:
        line_of.append(ln)
        if ch == "\n":
            ln += 1
    found = []
    for m in FN.finditer(src):
        # The body starts at the first `{` at bracket depth 0 after the signature; a `;`
        # first means a declaration without a body.
        depth, j = 0, m.end()
        while j < len(src):
            ch = src[j]
            if ch in "([<" and not (ch == "<" and src[j - 1] == "-"):
                depth += 1 if ch != "<" else 0
            if ch in "([":
                pass
            if ch in ")]":
                depth -= 1
            if depth <= 0 and ch in "{;":
                break
            j += 1
        if j >= len(src) or src[j] == ";":
            continue
        level, k = 0, j
        while k < len(src):
            if src[k] == "{":
                level += 1
            elif src[k] == "}":
                level -= 1
                if level == 0:
                    break
            k += 1
        start, end = line_of[m.start()], line_of[min(k, len(src) - 1)]
        found.append((start, end - start + 1, m.group(1)))
    return found


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--limit", type=int, default=150)
    ap.add_argument("paths", nargs="*", default=["crates"])
    args = ap.parse_args()
    rows = []
    for root in args.paths:
        walk = [(root, [], [os.path.basename(root)])] if os.path.isfile(root) else os.walk(root)
        for d, dirs, files in walk:
            dirs[:] = sorted(x for x in dirs if x not in ("target", ".git"))
            for f in sorted(files):
                if not f.endswith(".rs"):
                    continue
                p = root if os.path.isfile(root) else os.path.join(d, f)
                for line, length, name in functions(p):
                    if length > args.limit:
                        rows.append((length, p, line, name))
    rows.sort(key=lambda r: (-r[0], r[1], r[2]))
    for length, p, line, name in rows:
        print(f"{p}:{line}  {length}  {name}")
    print(f"{len(rows)} functions over {args.limit} lines", file=sys.stderr)


if __name__ == "__main__":
    main()
