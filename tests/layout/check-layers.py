#!/usr/bin/env python3
"""Fails when a lower layer includes a higher layer's header (docs/layout.md, "who may
include whom"). Headers are found by name, as the build finds them; a relative include
("../x.h") is resolved from the including file's folder.
Usage: tests/layout/check-layers.py [SOURCE_DIR]"""
import os, re, sys

# The most specific folder first.
LAYERS = [
    ('pipeline/core/', 'core'), ('pipeline/model/', 'model'), ('pipeline/geometry/', 'geometry'),
    ('pipeline/appearance/', 'appearance'), ('pipeline/calib/cv/', 'cv'), ('pipeline/calib/', 'calib'),
    ('pipeline/eval/', 'eval'), ('pipeline/export/', 'export'), ('pipeline/mosaic/', 'mosaic'),
    ('pipeline/', 'pipeline'), ('drivers/', 'drivers'), ('proto/', 'proto'), ('sim/emu/', 'emu'),
    ('sim/', 'sim'), ('daemon/', 'daemon'),
]
# What each layer may include besides itself; None: anything.
ALLOWED = {
    'core': [], 'model': ['core'], 'geometry': ['core', 'model'],
    'appearance': ['core', 'model', 'geometry'], 'calib': ['core', 'model'],
    'cv': ['core', 'model', 'calib'], 'eval': ['core', 'model', 'geometry', 'appearance'],
    'export': ['core', 'model', 'geometry', 'appearance'],
    'mosaic': ['core', 'model', 'geometry', 'appearance', 'export'],
    'pipeline': ['core', 'model', 'geometry', 'appearance', 'calib', 'cv', 'eval', 'export', 'mosaic'],
    'drivers': ['core', 'model'], 'proto': ['core', 'model'], 'emu': ['core', 'model'],
    'sim': ['core', 'model', 'emu'], 'daemon': ['core', 'model', 'drivers', 'proto'],
    'top': None,
}
INCLUDE = re.compile(r'^\s*#\s*include\s*"([^"]+)"')

def layer_of(path):
    for prefix, name in LAYERS:
        if path.startswith(prefix):
            return name
    return 'top'

def main():
    top = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(__file__), '..', '..'))
    files = []
    for root in ('pipeline', 'drivers', 'proto', 'sim', 'daemon'):
        for dp, dn, fn in os.walk(os.path.join(top, root)):
            files += [os.path.relpath(os.path.join(dp, f), top) for f in fn
                      if f.endswith(('.c', '.cpp', '.h', '.hpp'))]
    files.sort()
    header_layer = {}
    for f in files:
        if f.endswith(('.h', '.hpp')):
            name, l = os.path.basename(f), layer_of(f)
            if header_layer.get(name, l) != l:
                print(f'check-layers: header name {name} is in two layers ({header_layer[name]}, {l}): rename one')
                return 1
            header_layer[name] = l
    bad = checked = 0
    for f in files:
        src = layer_of(f)
        ok = ALLOWED[src]
        if ok is None:
            continue
        for n, line in enumerate(open(os.path.join(top, f), errors='replace'), 1):
            m = INCLUDE.match(line)
            if not m:
                continue
            inc = m.group(1)
            if '/' in inc:
                dst = layer_of(os.path.normpath(os.path.join(os.path.dirname(f), inc)))
            elif inc in header_layer:
                dst = header_layer[inc]
            else:
                continue            # a system or generated header
            checked += 1
            if dst != src and dst not in ok:
                print(f'{f}:{n}: layer \'{src}\' includes "{inc}" of layer \'{dst}\' (allowed: {" ".join(ok) or "none"})')
                bad += 1
    if checked < 100:
        print(f'check-layers: only {checked} includes checked; is {top} the source tree?')
        return 1
    if bad:
        print(f'check-layers: {bad} include(s) point up the layers')
        return 1
    print(f'check-layers: {checked} includes, every one points down the layers')
    return 0

sys.exit(main())
