#!/usr/bin/python3
"""Checks the shape of palp's tree (docs/architecture.md, "Modules and rooms"):

* every file of a library room includes palp headers only from its own room and the rooms
  below it (the include graph points down);
* no source folder holds more than 20 sources (.cpp and .c);
* no file of the library, the tools or the benchmarks passes 700 lines.

Run from anywhere: python3 tools/check_rooms.py. Prints every breach and exits 1 if there is
one; ctest runs it as `rooms`.
"""
import os
import re
import subprocess
import sys

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), '..'))

# The rooms, bottom up: the folder their files live in and the public include prefix of their
# headers.
ROOMS = {
    'base': ('kernels/base/', r'palp/base/'),
    'kernels': ('kernels/', r'palp/kernels/'),
    'volume': ('volume/', r'palp/volume/'),
    'fem': ('fem/', r'palp/fem/'),
    'tissue': ('haptics/tissue/', r'palp/haptics/tissue/'),
    'rendering': ('haptics/rendering/', r'palp/haptics/rendering/'),
    'devices': ('haptics/devices/', r'palp/haptics/devices/'),
    'runtime': ('haptics/runtime/', r'palp/haptics/[a-z_]+\.h$'),
    'studies': ('haptics/studies/', r'palp/studies/'),
    'capi': ('haptics/capi/', r'palp/palp(_[a-z]+)?\.h$'),
    'perception': ('haptics/perception/', r'palp/perception/'),
}
# What each room may include besides itself: the rooms below it that it builds on.
BELOW = {
    'base': [],
    'kernels': ['base'],
    'volume': ['base'],
    'fem': ['base', 'volume'],
    'tissue': ['base', 'kernels', 'volume', 'fem'],
    'rendering': ['base', 'kernels', 'volume', 'fem', 'tissue'],
    'devices': ['base', 'kernels', 'volume', 'fem', 'tissue', 'rendering'],
    'runtime': ['base', 'kernels', 'volume', 'fem', 'tissue', 'rendering', 'devices'],
    'studies': ['base', 'kernels', 'volume', 'fem', 'tissue', 'rendering', 'devices', 'runtime',
                'perception'],
    'capi': ['base', 'kernels', 'volume', 'fem', 'tissue', 'rendering', 'devices', 'runtime',
             'studies', 'perception'],
    # Psychophysics beside the haptics rooms: maths on numbers, no session or device.
    'perception': ['base'],
}
MAX_SOURCES = 20
MAX_LINES = 700
PRODUCTION = ('kernels/', 'volume/', 'fem/', 'haptics/', 'tools/', 'python/', 'bench/')
INCLUDE = re.compile(r'^\s*#\s*include\s*[<"](palp/[^>"]+)[>"]', re.M)


def room_of_file(path):
    """The room a repository path belongs to (the longest matching folder), or None."""
    matches = [room for room, (folder, _) in ROOMS.items() if path.startswith(folder)]
    return max(matches, key=lambda room: len(ROOMS[room][0]), default=None)


def room_of_header(header):
    """The room whose public prefix matches the include path @p header, or None."""
    for room, (_, prefix) in ROOMS.items():
        if re.match(prefix, header):
            return room
    return None


def main():
    files = subprocess.run(['git', 'ls-files'], cwd=ROOT, capture_output=True, text=True,
                           check=True).stdout.split()
    breaches = []
    per_folder = {}
    for path in files:
        if not path.endswith(('.cpp', '.c', '.h')):
            continue
        full = os.path.join(ROOT, path)
        if not os.path.isfile(full):
            continue
        if path.endswith(('.cpp', '.c')):
            per_folder.setdefault(os.path.dirname(path), []).append(path)
        text = open(full, encoding='utf-8').read()
        if path.startswith(PRODUCTION):
            lines = text.count('\n')
            if lines > MAX_LINES:
                breaches.append(f'{path}: {lines} lines, expected at most {MAX_LINES}')
        room = room_of_file(path)
        if room is None:
            continue
        allowed = set(BELOW[room]) | {room}
        for header in INCLUDE.findall(text):
            target = room_of_header(header)
            if target is None:
                breaches.append(f'{path}: includes {header}, which belongs to no room')
            elif target not in allowed:
                breaches.append(f'{path} (room {room}): includes {header} from room {target}, '
                                f'expected only {", ".join(sorted(allowed))}')
    for folder, sources in sorted(per_folder.items()):
        if len(sources) > MAX_SOURCES:
            breaches.append(f'{folder}/: {len(sources)} sources, expected at most {MAX_SOURCES}')
    if breaches:
        print('check_rooms: the tree breaks its rooms (docs/architecture.md):')
        for b in breaches:
            print('  ' + b)
        return 1
    print(f'check_rooms: {len(ROOMS)} rooms point down, {len(per_folder)} source folders of at most '
          f'{MAX_SOURCES} sources, no production file over {MAX_LINES} lines')
    return 0


if __name__ == '__main__':
    sys.exit(main())
