#!/usr/bin/env python3
"""Rewrite cites of the old, out-of-tree design notes in the crates' comments.

The source comments used to cite notes that lived outside the repository
(`algorithms.md §4.3`, `anny-assets.md §6.4`, `architecture.md §2`, `stack.md §2`, and bare
`§6.4`-style cites that mean one of those notes, depending on the crate).  The repository now
carries its own notes under docs/; docs/design/CITATIONS.tsv maps every old section to a new
one.  This script applies that map to

* `crates/**/*.rs`: text of `//`, `///` and `//!` comments (and, with --strings, string
  literals; one informative string in panoman-human's dataset.json writer cites a note);
* `crates/**/Cargo.toml`: text of `#` comments.

Usage (from the repository root):

    python3 tools/recite.py            # rewrite, print the replacements per file
    python3 tools/recite.py --strings  # also inside string literals
    python3 tools/recite.py --check    # exit 1 if an old cite is left (comments or strings)
    python3 tools/recite.py --list     # print every old cite found, with its new text

How a cite is read:

* `NAME.md §A[–B][ item(s) N[–M]][, §C ...]` (NAME one of algorithms, anny-assets,
  architecture, stack, style; `.md` may be missing when a section follows, e.g.
  `architecture §5`; the capitalised `Anny-assets.md` is accepted).  Each section is looked
  up as `NAME.md §A` (with the item suffix when there is one) in the TSV; a range `§A–B`
  maps both ends and is kept as a range when both land in the same file.  Sections separated
  by `, `, `/` or ` and ` belong to the same cite.
* `NAME.md` alone is looked up as `NAME.md`; when it ends a comment line and the next
  comment line starts with `§…`, the two lines form one cite.
* A bare `§A` (no note name) in panoman-human means anny-assets.md; in panoman-mesh and
  panoman-model it means algorithms.md; elsewhere bare cites are left alone.  A bare cite
  right after `paper`, `PanoMan`, `Appendix`, `Total Capture`, `TC`, `Eq.` (on the same
  line, or ending the previous comment line) cites the papers and is left alone, as is one
  right after a new path (`….md §3.1`), which makes the rewrite idempotent.
* TSV rows whose old text is not of the form `NAME.md[ §…]` are literal phrases; they are
  replaced first (e.g. `§6.3 of the asset notes`).

A cite whose section has no TSV row is an error (exit 2): the map must be complete.
Python 3.8+, standard library only.
"""

import argparse
import os
import re
import sys

DOCS = ("algorithms", "anny-assets", "architecture", "stack", "style")
DOC_NAME = r"(?<![/\w.-])(?P<name>[Aa]lgorithms|[Aa]nny-assets|[Aa]rchitecture|[Ss]tack|[Ss]tyle)(?P<md>\.md)?`?"
SEC = r"\d+(?:\.\d+)*"
REF = (
    r"§(?P<a{i}>" + SEC + r")(?:[–-](?P<b{i}>" + SEC + r"))?"
    r"(?:\s+(?P<it{i}>items?)\s+(?P<n{i}>\d+)(?:[–-](?P<m{i}>\d+))?)?"
)
ONE_REF = re.compile(REF.format(i=""))
REFS = r"§" + SEC + r"(?:[–-]" + SEC + r")?(?:\s+items?\s+\d+(?:[–-]\d+)?)?"
REF_LIST = REFS + r"(?:(?:,\s*|/|\s+and\s+)" + REFS + r")*"
SEPARATOR = re.compile(r"(,\s*|/|\s+and\s+)(?=§)")
CITE = re.compile(
    r"(?P<doc>" + DOC_NAME + r")(?:(?P<sp>[ \t]+)(?P<refs>" + REF_LIST + r"))?"
    r"|(?P<bare>" + REF_LIST + r")"
)
PAPER_BEFORE = re.compile(
    r"(paper|PanoMan|Appendix|Capture|TC|Eq\.|Eqs\.)[\s(]*$"
)
NEW_PATH_BEFORE = re.compile(r"\.md`?[\s(]*$")
ENDS_WITH_DOC = re.compile(DOC_NAME + r"\s*$")
SECTION_ROW = re.compile(
    r"^(?:algorithms|anny-assets|architecture|stack|style)\.md"
    r"(?: §" + SEC + r"(?: items? \d+(?:[–-]\d+)?)?)?$"
)

# Default note of a bare cite, by path prefix (relative to the repository root).
BARE_DEFAULT = (
    ("crates/panoman-human/", "anny-assets"),
    ("crates/panoman-mesh/", "algorithms"),
    ("crates/panoman-model/", "algorithms"),
)


class MapError(Exception):
    pass


def load_tsv(path):
    sections, literals = {}, []
    with open(path, encoding="utf-8") as f:
        for n, line in enumerate(f, 1):
            line = line.rstrip("\n")
            if not line or line.startswith("#"):
                continue
            parts = line.split("\t")
            if len(parts) != 2:
                raise SystemExit(f"{path}:{n}: expected old_text<TAB>new_text")
            old, new = parts
            if old == "old_text":
                continue
            if SECTION_ROW.match(old):
                sections[old] = new
            else:
                literals.append((old, new))
    # Longest literal first, so that a phrase wins over a shorter one inside it.
    literals.sort(key=lambda r: -len(r[0]))
    return sections, literals


def split_new(new):
    """'docs/design/x.md §3.2' -> ('docs/design/x.md', '3.2'); no section -> (path, None)."""
    if " §" in new:
        path, sec = new.rsplit(" §", 1)
        return path, sec
    return new, None


def lookup(sections, doc, key_suffix, where):
    key = f"{doc}.md{key_suffix}"
    if key not in sections:
        raise MapError(f"{where}: no row for `{key}` in the TSV")
    return split_new(sections[key])


def map_refs(sections, doc, refs_text, where):
    """Maps a list of refs of one note; returns [(path, text_after_path, separator_before)]."""
    out = []
    pos = 0
    seps = [""]
    pieces = []
    for m in SEPARATOR.finditer(refs_text):
        pieces.append(refs_text[pos:m.start()])
        seps.append(m.group(1))
        pos = m.end()
    pieces.append(refs_text[pos:])
    for sep, piece in zip(seps, pieces):
        m = ONE_REF.fullmatch(piece)
        if not m:
            raise MapError(f"{where}: cannot read the section `{piece}`")
        a, b, it, n, mm = m.group("a"), m.group("b"), m.group("it"), m.group("n"), m.group("m")
        if it:
            suffix = f" §{a} {it} {n}" + (f"–{mm}" if mm else "")
            path, sec = lookup(sections, doc, suffix, where)
            out.append((path, sec, sep))
            continue
        path, sec = lookup(sections, doc, f" §{a}", where)
        if b:
            path_b, sec_b = lookup(sections, doc, f" §{b}", where)
            if path_b == path and sec is not None and sec_b is not None:
                out.append((path, f"{sec}–{sec_b}" if sec != sec_b else sec, sep))
            else:
                out.append((path, sec, sep))
                out.append((path_b, sec_b, " to "))
        else:
            out.append((path, sec, sep))
    return out


def render(mapped, with_first_path=True):
    text = ""
    last_path = None
    for i, (path, sec, sep) in enumerate(mapped):
        if i > 0:
            text += sep
        show_path = path != last_path and (i > 0 or with_first_path)
        if show_path:
            text += path
            if sec is not None:
                text += f" §{sec}"
        else:
            text += f"§{sec}" if sec is not None else ""
        last_path = path
    return text


def comment_spans(lines, kind):
    """Per line: the (start, end) span of its comment (or None) and the spans of its string
    literals. `kind` is 'rs' or 'toml'. Rust strings may run over several lines."""
    comments, strings = [], []
    in_str = False
    for line in lines:
        com, st = None, []
        i, n = 0, len(line)
        str_start = 0 if in_str else None
        while i < n:
            c = line[i]
            if in_str:
                if c == "\\":
                    i += 2
                    continue
                if c == '"':
                    in_str = False
                    st.append((str_start, i))
                    str_start = None
                i += 1
                continue
            if (kind == "rs" and line.startswith("//", i)) or (kind == "toml" and c == "#"):
                com = (i, n)
                break
            if c == '"':
                in_str = True
                str_start = i + 1
            elif kind == "rs" and c == "'":
                # A char literal ('x', '\\n', '"'); a lifetime ('a) is left alone.
                if i + 1 < n and line[i + 1] == "\\":
                    j = line.find("'", i + 2)
                    i = (j + 1) if j > 0 else i + 1
                    continue
                if i + 2 < n and line[i + 2] == "'":
                    i += 3
                    continue
            i += 1
        if in_str and str_start is not None:
            st.append((str_start, n))
        if kind == "toml":
            in_str = False
        comments.append(com)
        strings.append(st)
    return comments, strings


def rewrite_text(text, sections, literals, bare_doc, where, prev_text, carry_doc, count):
    """Rewrites the text of one comment (or string literal).

    `prev_text` is the previous comment line's text (for cites split after `paper`),
    `carry_doc` the note named at the end of the previous comment line when this line goes on
    with its sections."""
    for old, new in literals:
        if old in text:
            count[0] += text.count(old)
            text = text.replace(old, new)
    out = []
    pos = 0
    for m in CITE.finditer(text):
        before = text[:m.start()]
        new = None
        if m.group("doc"):
            name = m.group("name").lower()
            if m.group("refs"):
                new = render(map_refs(sections, name, m.group("refs"), where))
            elif m.group("md"):
                path, sec = lookup(sections, name, "", where)
                new = path + (f" §{sec}" if sec else "")
        else:
            start_of_line = before.strip() == ""
            if start_of_line and carry_doc:
                mapped = map_refs(sections, carry_doc, m.group("bare"), where)
                new = render(mapped, with_first_path=False)
            elif PAPER_BEFORE.search(before) or NEW_PATH_BEFORE.search(before):
                new = None
            elif start_of_line and (PAPER_BEFORE.search(prev_text)
                                    or NEW_PATH_BEFORE.search(prev_text)):
                new = None
            elif bare_doc:
                new = render(map_refs(sections, bare_doc, m.group("bare"), where))
        if new is not None and new != m.group(0):
            out.append(text[pos:m.start()])
            out.append(new)
            pos = m.end()
            count[0] += 1
    out.append(text[pos:])
    return "".join(out)


LEAD = re.compile(r"\s*(?://[/!]?|#)\s*")


def process_file(path, rel, sections, literals, with_strings):
    kind = "toml" if path.endswith(".toml") else "rs"
    with open(path, encoding="utf-8") as f:
        original = f.read()
    lines = original.split("\n")
    comments, strings = comment_spans(lines, kind)
    bare_doc = None
    if kind == "rs":
        for prefix, doc in BARE_DEFAULT:
            if rel.startswith(prefix):
                bare_doc = doc
    count = [0]
    new_lines = list(lines)
    changes = []
    prev_body, carry = "", None
    for ln, line in enumerate(lines):
        where = f"{rel}:{ln + 1}"
        edits = []  # (start, end, new_text)
        next_carry = None
        if comments[ln]:
            s, e = comments[ln]
            text = line[s:e]
            lead = LEAD.match(text).group(0)
            body = text[len(lead):]
            tail = ""
            # A note name ending this comment, its sections starting the next one: one cite.
            m_end = ENDS_WITH_DOC.search(body)
            nxt = comments[ln + 1] if ln + 1 < len(lines) else None
            if m_end and m_end.group("md") and nxt:
                nxt_text = lines[ln + 1][nxt[0]:nxt[1]]
                nxt_body = nxt_text[len(LEAD.match(nxt_text).group(0)):]
                first = re.match(REF_LIST, nxt_body)
                if first:
                    doc = m_end.group("name").lower()
                    mapped = map_refs(sections, doc, first.group(0), where)
                    body, tail = body[:m_end.start()], mapped[0][0]
                    next_carry = doc
                    count[0] += 1
            new_body = rewrite_text(body, sections, literals, bare_doc, where, prev_body,
                                    carry, count) + tail
            edits.append((s, e, lead + new_body))
            prev_body = body
        else:
            prev_body = ""
        carry = next_carry
        if with_strings:
            for (s, e) in strings[ln]:
                seg = line[s:e]
                edits.append((s, e, rewrite_text(seg, sections, literals, None, where, "",
                                                 None, count)))
        new_line = line
        for (s, e, t) in sorted(edits, reverse=True):
            new_line = new_line[:s] + t + new_line[e:]
        if new_line != line:
            changes.append((ln + 1, line.strip(), new_line.strip()))
        new_lines[ln] = new_line
    string_hits = []
    for ln, st in enumerate(strings):
        for (s, e) in st:
            seg = lines[ln][s:e]
            if OLD_NAME_IN_STRING.search(seg):
                string_hits.append((ln + 1, seg.strip()))
    return "\n".join(new_lines), count[0], changes, string_hits


OLD_NAME_IN_STRING = re.compile(r"(?<![/\w.-])(?:algorithms|anny-assets|architecture|stack|style)\.md", re.I)


def find_files(root):
    out = []
    base = os.path.join(root, "crates")
    for dirpath, dirnames, filenames in os.walk(base):
        dirnames[:] = sorted(d for d in dirnames if d != "target" and not d.startswith("."))
        for fn in sorted(filenames):
            if fn.endswith(".rs") or fn == "Cargo.toml":
                full = os.path.join(dirpath, fn)
                out.append((full, os.path.relpath(full, root).replace(os.sep, "/")))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--root", default=".", help="repository root (default: .)")
    ap.add_argument("--tsv", default=None, help="default: ROOT/docs/design/CITATIONS.tsv")
    ap.add_argument("--check", action="store_true",
                    help="change nothing; exit 1 if an old cite is left")
    ap.add_argument("--strings", action="store_true",
                    help="also rewrite cites inside string literals")
    ap.add_argument("--list", action="store_true",
                    help="change nothing; print each rewrite that would be made")
    args = ap.parse_args()
    root = args.root
    tsv = args.tsv or os.path.join(root, "docs", "design", "CITATIONS.tsv")
    sections, literals = load_tsv(tsv)
    total, left, errors = 0, 0, 0
    for full, rel in find_files(root):
        try:
            text, n, changes, string_hits = process_file(
                full, rel, sections, literals, args.strings or args.check)
        except MapError as e:
            print(f"error: {e}", file=sys.stderr)
            errors += 1
            continue
        if args.check:
            for ln, old, new in changes:
                print(f"{rel}:{ln}: old cite: {old}")
            left += len(changes)
            continue
        if not args.strings:
            for ln, seg in string_hits:
                print(f"note: {rel}:{ln}: cite inside a string literal left as is "
                      f"(use --strings): {seg}", file=sys.stderr)
        if args.list:
            for ln, old, new in changes:
                print(f"{rel}:{ln}:\n  - {old}\n  + {new}")
        if n:
            total += n
            print(f"{rel}: {n} replacement{'s' if n != 1 else ''}")
            if not args.list:
                with open(full, "w", encoding="utf-8") as f:
                    f.write(text)
    if errors:
        return 2
    if args.check:
        if left:
            print(f"{left} line(s) still cite the old notes", file=sys.stderr)
            return 1
        print("no old cites left")
        return 0
    print(f"total: {total} replacement{'s' if total != 1 else ''}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
