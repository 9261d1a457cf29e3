#!/usr/bin/env python3
"""Lists C/C++ functions longer than a limit (default 120 lines), body braces included.
A function may be exempted by a comment `/* hot loop: … */` on the line before its
signature or within its first three lines: a documented hot loop (docs/layout.md).
Exit 1 when any function outside tests/ is over the limit.
Usage: long-functions.py [--limit N] [--all] DIR..."""
import os, re, sys

def strip(text):
    # blank out comments and string/char literals, keeping line structure
    out = []; i = 0; n = len(text)
    while i < n:
        c = text[i]
        if text.startswith('/*', i):
            j = text.find('*/', i + 2); j = n if j < 0 else j + 2
            out.append(re.sub(r'[^\n]', ' ', text[i:j])); i = j
        elif text.startswith('//', i):
            j = text.find('\n', i); j = n if j < 0 else j
            out.append(' ' * (j - i)); i = j
        elif c in '"\'':
            j = i + 1
            while j < n and text[j] != c and text[j] != '\n':
                j += 2 if text[j] == '\\' else 1
            out.append(c + ' ' * (j - i - 1) + (c if j < n else '')); i = j + 1
        else:
            out.append(c); i += 1
    return ''.join(out)

def functions(path):
    raw = open(path, errors='replace').read()
    lines = strip(raw).split('\n'); rawl = raw.split('\n')
    depth = 0; start = None; name = None
    for i, l in enumerate(lines):
        if l.lstrip().startswith('#'):
            continue
        for ch in l:
            if ch == '{':
                if depth == 0:
                    # the signature: this line or the lines above up to a ')' ... find a name(
                    k = i; sig = ''
                    while k >= 0 and k > i - 8:
                        sig = lines[k] + ' ' + sig
                        if re.match(r'^[A-Za-z_]', lines[k]): break
                        k -= 1
                    m = re.search(r'([A-Za-z_][A-Za-z_0-9:~]*)\s*\([^;]*\)\s*(const\s*)?(noexcept\s*)?(->[^{]*)?\{?\s*$', sig.strip())
                    bad = re.match(r'^\s*(struct|enum|union|typedef|static\s+const|const|namespace|extern)\b', sig) or '=' in sig.split('(')[0]
                    if m and not bad:
                        start = k; name = m.group(1)
                    else:
                        start = None
                depth += 1
            elif ch == '}':
                depth -= 1
                if depth == 0 and start is not None:
                    head = '\n'.join(rawl[max(0, start - 1):start + 4])
                    yield name, start + 1, i - start + 1, 'hot loop:' in head
                    start = None

def main():
    args = sys.argv[1:]; limit = 120; show_all = False
    if args[:1] == ['--limit']: limit = int(args[1]); args = args[2:]
    if args[:1] == ['--all']: show_all = True; args = args[1:]
    over = []
    for root in args:
        for dp, dn, fn in os.walk(root):
            dn[:] = [d for d in dn if not d.startswith('build') and d != 'node_modules']
            for f in sorted(fn):
                if f.endswith(('.c', '.cpp')):
                    p = os.path.join(dp, f)
                    for name, line, n, hot in functions(p):
                        if n > limit and not hot:
                            over.append((n, p, line, name))
    over.sort(reverse=True)
    fail = [o for o in over if '/tests/' not in '/' + o[1] and not o[1].startswith('tests/')]
    for n, p, line, name in (over if show_all else fail):
        print(f'{p}:{line}: {name}() is {n} lines (limit {limit})')
    print(f'long-functions: {len(fail)} function(s) over {limit} lines outside tests/', file=sys.stderr)
    return 1 if fail else 0

sys.exit(main())
