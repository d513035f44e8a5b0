#!/usr/bin/env python3
"""The docs and the code describe the project as it is, not the diary of how it
was built. Two kinds of wording fail:

  - a work session by its number or place: "the tenth session", "2nd session",
    "session 9", "this/last/next/previous session" (but not a WebSocket
    session's own words: "last session serial", "this session id", ...;
    "this/last/next session" is otherwise read as a work session: say "this
    connection" or "the client's session" where a WebSocket is meant);
  - an issue tracker's number: "issue 12", "issue #12", "issues 7 and 16",
    "issue15" in a test or target name. Readers have no access to that
    tracker: a comment says why, not which ticket. A URL's ".../issues/12" is
    not matched.

Scanned: README.md, docs/, proto/PROTOCOL.md and every text file of server/,
proto/ (not its binary test vectors), tools/, web/src, tests/, bench/, fuzz/
(not its corpus), scripts/, mk/, Makefile and docker/: comments, strings,
test names and make targets alike.

The rules are also run on a scratch tree with planted lines, each of which
must be caught, and with legitimate lines, none of which may be: a check
that cannot fail proves nothing. Last line: "N passed, N failed"."""
import os
import re
import sys
import tempfile

ORDINALS = ("first|second|third|fourth|fifth|sixth|seventh|eighth|ninth|tenth|"
            "eleventh|twelfth|thirteenth|fourteenth|fifteenth|[0-9]+(?:st|nd|rd|th)")
# Words after "this/last/next/previous session" that make it a WebSocket
# session's field, not a work session.
SESSION_FIELDS = "serial|id|ids|key|struct|object|pointer|state|buffer"
RULES = [
    ("work session", re.compile(
        rf"(?<![A-Za-z])(?:(?:{ORDINALS})[ -]session"
        rf"|(?:this|last|next|previous)\s+session\b(?!\s+(?:{SESSION_FIELDS})\b)"
        rf"|(?<![A-Za-z])sessions?[ _-]?#?[0-9]+)", re.I)),
    ("issue number", re.compile(r"(?<![A-Za-z])issues?(?:[ _-]*#?|#)[0-9]+", re.I)),
]

# Where to look, relative to the root: files, and folders walked recursively.
FILES = ("README.md", "proto/PROTOCOL.md", "Makefile")
FOLDERS = ("docs", "server", "proto", "tools", "web/src", "tests", "bench",
           "fuzz", "scripts", "mk", "docker")
SKIP_DIRS = {"node_modules", "build", ".git", "corpus", "regressions", "vectors", "__pycache__"}
TEXT_EXT = (".md", ".c", ".h", ".py", ".js", ".mjs", ".sh", ".mk", ".txt", ".yml",
            ".yaml", ".json", ".html", ".css", ".service", ".dockerignore")
TEXT_NAMES = ("Makefile", "Dockerfile")
# This file names the patterns it looks for.
ALLOW_FILES = {"tests/layout/test_wording.py"}


def files(root):
    for rel in FILES:
        if os.path.isfile(os.path.join(root, rel)):
            yield rel
    for top in FOLDERS:
        for dirpath, dirs, names in os.walk(os.path.join(root, top)):
            dirs[:] = sorted(d for d in dirs if d not in SKIP_DIRS)
            for name in sorted(names):
                if name.endswith(TEXT_EXT) or name in TEXT_NAMES:
                    yield os.path.relpath(os.path.join(dirpath, name), root)


def check(root):
    """Every line of diary wording under root, as "path:line: kind: text"."""
    bad = []
    for rel in sorted(set(files(root)) - ALLOW_FILES):
        with open(os.path.join(root, rel), encoding="utf-8", errors="replace") as f:
            for n, line in enumerate(f, 1):
                for kind, rx in RULES:
                    m = rx.search(line)
                    if m:
                        bad.append(f"{rel}:{n}: {kind} \"{m.group(0)}\": {line.strip()[:120]}")
    return bad


def plant(root, rel, text):
    path = os.path.join(root, rel)
    os.makedirs(os.path.dirname(path) or root, exist_ok=True)
    with open(path, "w") as f:
        f.write(text + "\n")


MUST_CATCH = [
    ("an ordinal session in the README", "README.md", "Measured in the tenth session (load 1)."),
    ("a numbered ordinal session", "docs/x.md", "As the 2nd session found, ..."),
    ("\"session 9\" in a doc", "docs/simulation.md", "**Streaming stores (session 9).**"),
    ("\"last session\" in a comment", "web/src/x.js", "// the same as last session"),
    ("an issue number in a comment", "server/base/x.c", "/* the bound of issue 15 */"),
    ("\"issue #12\"", "tests/x.py", "# see issue #12"),
    ("\"issues 7 and 16\"", "proto/PROTOCOL.md", "Figures of issues 7 and 16."),
    ("an issue in a make target", "mk/x.mk", "bench-issue15: bench-capacity"),
    ("an issue in a test name", "tests/daemon/t.py", "def test_issue_16_hostile():"),
    ("an issue in a Makefile", "Makefile", "# issue 3: the one package list"),
    ("an issue in docker/", "docker/Dockerfile", "# issue 4"),
]
MUST_PASS = [
    ("a tracker URL", "docs/y.md", "See https://github.com/nats-io/nats.c/issues/123 for it."),
    ("a WebSocket session's serial", "server/net/y.h", "uint64_t next_serial; /* last session serial handed out */"),
    ("a WebSocket session", "docs/z.md", "Each WebSocket session has its own buffer; a new session starts clean, session by session."),
    ("\"issued by\"", "docs/w.md", "JWT + NKey seed (as issued by `nsc`), 12 of them"),
    ("the word issue without a number", "README.md", "A known issue: TLS needs a restart."),
]


def main():
    root = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else ".")
    passed = failed = 0
    bad = check(root)
    for line in bad:
        print("wording:", line)
    if bad:
        failed += 1
        print(f"FAIL: {len(bad)} lines speak of work sessions or issue numbers "
              "(say what is true now, or why; git log keeps the history)")
    else:
        passed += 1
        print("ok: no work-session diary and no issue numbers")
    for what, rel, text in MUST_CATCH:
        with tempfile.TemporaryDirectory() as tmp:
            plant(tmp, rel, text)
            caught = check(tmp)
        if caught:
            passed += 1
            print(f"ok: {what} is caught ({caught[0]})")
        else:
            failed += 1
            print(f"FAIL: {what} is not caught")
    for what, rel, text in MUST_PASS:
        with tempfile.TemporaryDirectory() as tmp:
            plant(tmp, rel, text)
            caught = check(tmp)
        if not caught:
            passed += 1
            print(f"ok: {what} is not flagged")
        else:
            failed += 1
            print(f"FAIL: {what} is flagged ({caught[0]})")
    print(f"{passed} passed, {failed} failed")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
