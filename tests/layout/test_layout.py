#!/usr/bin/env python3
"""The source tree's shape, checked: server/ holds main.c and folders only,
no daemon file is over 800 lines, no two files share a name, a folder's
*_internal.h is included only inside that folder, and no daemon code looks a
sea parameter up by its name (the parameter table's flags say what a row
is). Each rule is also run on a copy of the tree with one violation planted,
and must catch it: a check that cannot fail proves nothing."""
import os
import re
import shutil
import sys
import tempfile

MAX_LINES = 800
# Files that may name parameters: the table itself and config-file I/O.
NAME_LOOKUP_ALLOWED = ("server/sim/params.c", "server/config/")


def server_files(root):
    for dirpath, _, files in os.walk(os.path.join(root, "server")):
        for f in files:
            if f.endswith((".c", ".h")):
                yield os.path.relpath(os.path.join(dirpath, f), root)


def check(root):
    """Every violation of the layout rules under root, as text lines."""
    bad = []
    top = os.path.join(root, "server")
    for entry in sorted(os.listdir(top)):
        if entry != "main.c" and not os.path.isdir(os.path.join(top, entry)):
            bad.append(f"server/{entry}: only main.c and folders belong at the top of server/")
    seen = {}
    for rel in sorted(server_files(root)):
        text = open(os.path.join(root, rel), encoding="utf-8", errors="replace").read()
        if rel.endswith(".c") and text.count("\n") > MAX_LINES:
            bad.append(f"{rel}: {text.count(chr(10))} lines (at most {MAX_LINES}: split it by concern)")
        base = os.path.basename(rel)
        if base in seen:
            bad.append(f"{rel}: same name as {seen[base]}")
        seen.setdefault(base, rel)
        folder = os.path.dirname(rel)
        for inc in re.findall(r'#include "([^"]+_internal\.h)"', text):
            owner = [r for r in server_files(root) if os.path.basename(r) == os.path.basename(inc)]
            if owner and all(os.path.dirname(o) != folder for o in owner):
                bad.append(f"{rel}: includes {inc}, internal to {os.path.dirname(owner[0])}/")
        if not rel.startswith(NAME_LOOKUP_ALLOWED):
            for m in re.finditer(r'param_find\(\s*"([^"]*)"', text):
                bad.append(f"{rel}: looks up parameter \"{m.group(1)}\" by name (use a PARAM_* flag)")
    return bad


def plant(root, rel, text, append=False):
    path = os.path.join(root, rel)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with open(path, "a" if append else "w") as f:
        f.write(text)


def main():
    root = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else ".")
    passed = failed = 0
    bad = check(root)
    for line in bad:
        print("layout:", line)
    if bad:
        failed += 1
    else:
        passed += 1
        print("ok: the tree follows the layout rules")
    # Each planted violation must be caught, and by the right rule.
    plants = [
        ("a file at the top of server/", lambda r: plant(r, "server/stray.c", "int x;\n"), "only main.c"),
        ("a file over the limit", lambda r: plant(r, "server/base/huge.c", "\n" * (MAX_LINES + 1)), "lines"),
        ("two files with one name", lambda r: plant(r, "server/net/log.c", "int y;\n"), "same name"),
        ("another folder's internal header", lambda r: plant(
            r, "server/base/peek.c", '#include "tick_internal.h"\n'), "internal to"),
        ("a parameter looked up by name", lambda r: plant(
            r, "server/tick/frame.c", 'static void f(void) { param_find("resolution"); }\n', append=True),
         "by name"),
    ]
    for what, make, expect in plants:
        with tempfile.TemporaryDirectory() as tmp:
            shutil.copytree(os.path.join(root, "server"), os.path.join(tmp, "server"))
            make(tmp)
            caught = [b for b in check(tmp) if expect in b]
        if caught:
            passed += 1
            print(f"ok: {what} is caught ({caught[0]})")
        else:
            failed += 1
            print(f"FAIL: {what} is not caught")
    print(f"{passed} passed, {failed} failed")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
