#!/usr/bin/env python3
"""md2man.py SRC.md OUT.roff [--version V] [--help-of NAME=PROGRAM ARGS...]

Converts one man page written in the small Markdown subset of docs/man/ into roff (man(7)
macros), so each page has one source that is read both on GitHub and by man(1):

  % NAME(SECTION) | TITLE        first line: the page's .TH
  # HEADING / ## SUBHEADING      .SH / .SS
  **bold** *italic* `code`       \\fB \\fI \\fB (code is bold, as options are in man pages)
  TERM line, then ": text"       a tagged paragraph (.TP): options, fields, files
  - item                         a bullet (.IP)
  ```  …  ```                    a literal block (.nf), indented
  blank line                     a new paragraph (.PP)
  @VERSION@                      the project's version
  @COMMANDS@                     impasto's command list, taken from `impasto help` (the
                                 command table of cli/main.c) with --help-of impasto=BINARY
  @HELP:NAME@                    PROGRAM --help verbatim (a literal block), for NAME given
                                 with --help-of NAME=PROGRAM
"""
import re
import subprocess
import sys


def inline(text):
    out, i = [], 0
    text = text.replace("\\", "\\e")
    # roff: a hyphen in an option is a minus (\-) so that it can be searched and copied
    for m in re.finditer(r"\*\*(.+?)\*\*|`(.+?)`|\*(.+?)\*", text):
        out.append(plain(text[i:m.start()]))
        if m.group(1) is not None:
            out.append("\\fB" + plain(m.group(1), True) + "\\fR")
        elif m.group(2) is not None:
            out.append("\\fB" + plain(m.group(2), True) + "\\fR")
        else:
            out.append("\\fI" + plain(m.group(3), True) + "\\fR")
        i = m.end()
    out.append(plain(text[i:]))
    s = "".join(out)
    if s.startswith((".", "'")):
        s = "\\&" + s
    return s


def plain(s, code=False):
    s = s.replace("-", "\\-") if code else re.sub(r"(?<![\w])-", "\\-", s)
    return s.replace("…", "\\&...").replace("—", "\\(em").replace("–", "\\(en").replace("→", "\\(->")


def literal(lines):
    out = [".PP", ".RS 4", ".nf"]
    for l in lines:
        l = l.replace("\\", "\\e")
        out.append(("\\&" + l) if l.startswith((".", "'")) else l)
    out += [".fi", ".RE"]
    return out


def help_text(cmd):
    r = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=60)
    return r.stdout.rstrip("\n").split("\n")


def commands(impasto):
    """The command list of `impasto help`: lines '  NAME  SUMMARY' under 'commands:'."""
    out, on = [], False
    for l in help_text(impasto + ["help"]):
        if l.startswith("commands:"):
            on = True
        elif on and re.match(r"^  [a-z_-]+ ", l):
            name, summary = l.split(None, 1)
            out += [".TP", "\\fB" + name.replace("-", "\\-") + "\\fR", inline(summary.strip())]
        elif on and not l.strip():
            break
    if not out:
        sys.exit("md2man: no command list in the output of %s help" % " ".join(impasto))
    return out


def convert(src, version, helps):
    lines = open(src, encoding="utf-8").read().split("\n")
    m = re.match(r"^% ([\w.-]+)\((\d)\) \| (.+)$", lines[0])
    if not m:
        sys.exit("%s:1: expected '%% NAME(SECTION) | TITLE'" % src)
    out = ['.TH "%s" "%s" "" "impasto %s" "%s"' % (m.group(1).upper(), m.group(2), version, m.group(3))]
    i, para = 1, False
    while i < len(lines):
        l = lines[i].rstrip()
        nxt = lines[i + 1] if i + 1 < len(lines) else ""
        if l.startswith("```"):
            j = i + 1
            while j < len(lines) and not lines[j].startswith("```"):
                j += 1
            if j == len(lines):
                sys.exit("%s:%d: unterminated ``` block" % (src, i + 1))
            out += literal(lines[i + 1:j])
            i, para = j + 1, False
            continue
        if l == "@COMMANDS@":
            out += commands(helps["impasto"])
        elif re.fullmatch(r"@HELP:[\w-]+@", l):
            out += literal(help_text(helps[l[6:-1]] + ["--help"]))
        elif l.startswith("## "):
            out.append('.SS "%s"' % inline(l[3:]))
        elif l.startswith("# "):
            out.append(".SH %s" % inline(l[2:]).upper())
        elif not l:
            para = False
        elif nxt.startswith(": "):
            out += [".TP", inline(l)]
            i += 1
            out.append(inline(lines[i][2:].replace("@VERSION@", version)))
            while i + 1 < len(lines) and lines[i + 1].startswith("  ") and lines[i + 1].strip():
                i += 1
                out.append(inline(lines[i].strip()))
            para = True
        elif l.startswith("- "):
            out += [".IP \\(bu 2", inline(l[2:])]
            para = True
        elif l.startswith("  ") and para:
            out.append(inline(l.strip()))
        else:
            if not para:
                out.append(".PP")
            out.append(inline(l.replace("@VERSION@", version)))
            para = True
        i += 1
    return "\n".join(out) + "\n"


def main():
    a = sys.argv[1:]
    src, dst, version, helps = a[0], a[1], "", {}
    a = a[2:]
    while a:
        if a[0] == "--version":
            version, a = a[1], a[2:]
        elif a[0] == "--help-of":
            name, prog = a[1].split("=", 1)
            helps[name], a = prog.split(";"), a[2:]
        else:
            sys.exit("md2man: unknown argument %s" % a[0])
    text = convert(src, version, helps)
    with open(dst, "w", encoding="utf-8") as f:
        f.write(text)


if __name__ == "__main__":
    main()
