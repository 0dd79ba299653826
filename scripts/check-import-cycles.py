#!/usr/bin/env python3
"""Fails when a source file imports, directly or through others, a module that imports it back.

Within each crate of the workspace: a file's imports are the modules its `use` trees and inline
`crate::`/`super::`/`self::` paths resolve to (the deepest module file a path names). Declaring a
child (`mod x;`) is not an import; `use x::Item` is. Cross-crate
imports cannot form cycles (cargo forbids them) and are not followed. A `pub use` re-export
publishes an item rather than using it: it is no import, and a path through it
(`crate::warm::Item`, re-exported by `warm/mod.rs` from `warm/model.rs`) resolves to the file the
item comes from.

Usage: scripts/check-import-cycles.py [ROOT]   (ROOT: the workspace, default: this repository)
"""
import os
import re
import sys

ROOT = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(__file__), ".."))
SKIP = {"target", ".git", "fuzz", "node_modules"}


def strip_comments_and_strings(text):
    """Source with comments and string literals blanked (paths in docs do not count)."""
    text = re.sub(r"/\*.*?\*/", " ", text, flags=re.S)
    text = re.sub(r'r#*"(?:.|\n)*?"#*', '""', text)
    text = re.sub(r'"(?:\\.|[^"\\])*"', '""', text)
    return re.sub(r"//[^\n]*", "", text)


class Crate:
    """The module tree of one crate root: module path (tuple) -> file, with each file's
    directory for child modules."""

    def __init__(self, root_file):
        self.files = {}  # module path -> file
        self.module_of = {}  # file -> module path
        self.reexports = {}  # file -> {published name: path segments}
        self.walk(root_file, ())

    def walk(self, path, module):
        self.files[module] = path
        self.module_of[path] = module
        text = strip_comments_and_strings(open(path, encoding="utf-8").read())
        published = {}
        for segments, alias in use_paths(text, public=True):
            if segments:
                published[alias or segments[-1]] = segments
        self.reexports[path] = published
        base = os.path.basename(path)
        child_dir = (
            os.path.dirname(path)
            if base in ("lib.rs", "main.rs", "mod.rs") or module == ()
            else os.path.join(os.path.dirname(path), base[:-3])
        )
        for m in re.finditer(r"^\s*(?:pub(?:\([^)]*\))?\s+)?mod\s+(\w+)\s*;", text, flags=re.M):
            name = m.group(1)
            for candidate in (os.path.join(child_dir, name + ".rs"), os.path.join(child_dir, name, "mod.rs")):
                if os.path.exists(candidate):
                    self.walk(candidate, module + (name,))
                    break

    def resolve(self, file, segments, depth=0, inline=0):
        """The module file a path (`crate::a::b::Item`, `super::x`, `self::y`, `child::z`) names,
        through re-exports, or None when it leaves the crate. `inline`: how many inline modules
        (`mod tests { .. }`) of the file the path stands in; their `super` stays in the file."""
        here = self.module_of[file]
        if not segments:
            return None
        head, rest = segments[0], segments[1:]
        if head == "crate":
            module = ()
        elif head in ("super", "self"):
            module = here
            while segments and segments[0] in ("super", "self"):
                if segments[0] == "super":
                    if inline > 0:
                        inline -= 1
                    else:
                        module = module[:-1]
                segments = segments[1:]
            rest = segments
        elif here + (head,) in self.files:
            module, rest = here + (head,), rest
        else:
            return None  # another crate, std, or a local item
        for i, seg in enumerate(rest):
            if module + (seg,) in self.files:
                module = module + (seg,)
                continue
            target = self.files[module]
            source = self.reexports[target].get(seg)
            if source and depth < 16:
                return self.resolve(target, source + rest[i + 1 :], depth + 1) or target
            break
        return self.files[module]


def use_paths(text, public=False, with_offsets=False):
    """Every path a file's private (or, with `public`, its `pub`) `use` trees name, as
    (segments, alias) pairs: `use a::{b, c::d as e}` -> (a::b, None), (a::c::d, e)."""
    paths = []
    for m in re.finditer(r"(\bpub(?:\([^)]*\))?\s+)?\buse\s+([^;]+);", text):
        if bool(m.group(1)) != public:
            continue
        tree = re.sub(r"\s+", " ", m.group(2)).strip()
        found = []
        expand(tree, [], found)
        paths.extend((m.start(), p, a) for p, a in found) if with_offsets else paths.extend(found)
    return paths


def expand(tree, prefix, out):
    depth, start, parts = 0, 0, []
    # Split on top-level commas only when the tree is a group.
    if tree.endswith("}") and "{" in tree:
        brace = tree.index("{")
        head = [s.strip() for s in tree[:brace].split("::") if s.strip()]
        inner = tree[brace + 1 : -1]
        for i, ch in enumerate(inner):
            if ch == "{":
                depth += 1
            elif ch == "}":
                depth -= 1
            elif ch == "," and depth == 0:
                parts.append(inner[start:i])
                start = i + 1
        parts.append(inner[start:])
        for part in parts:
            if part.strip():
                expand(part.strip(), prefix + head, out)
        return
    path, _, alias = tree.partition(" as ")
    segs = [s.strip() for s in path.split("::") if s.strip() and s.strip() != "*"]
    out.append((prefix + segs, alias.strip() or None))


def inline_paths(text):
    return [(m.start(), m.group(0).split("::")) for m in re.finditer(r"\b(?:crate|super|self)(?:::\w+)+", text)]


def inline_modules(text):
    """The (start, end) offsets of every inline module body (`mod tests { .. }`)."""
    spans = []
    for m in re.finditer(r"\bmod\s+\w+\s*\{", text):
        depth, i = 1, m.end()
        while i < len(text) and depth:
            depth += {"{": 1, "}": -1}.get(text[i], 0)
            i += 1
        spans.append((m.end(), i))
    return spans


def nesting(spans, offset):
    return sum(1 for a, b in spans if a <= offset < b)


def crate_roots():
    for dirpath, dirnames, filenames in os.walk(ROOT):
        dirnames[:] = [d for d in dirnames if d not in SKIP and not d.startswith(".")]
        if os.path.basename(dirpath) == "src":
            for root in ("lib.rs", "main.rs"):
                if root in filenames:
                    yield os.path.join(dirpath, root)
            bin_dir = os.path.join(dirpath, "bin")
            if os.path.isdir(bin_dir):
                for f in sorted(os.listdir(bin_dir)):
                    if f.endswith(".rs"):
                        yield os.path.join(bin_dir, f)


def cycles(graph):
    """Each cycle once, as a list of files (Tarjan's strongly connected components)."""
    index, low, stack, on, found, counter = {}, {}, [], set(), [], [0]

    def connect(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    sys.setrecursionlimit(10000)
    for v in list(graph):
        if v not in index:
            connect(v)
    return found


def main():
    problems = []
    files_checked = 0
    for root in crate_roots():
        crate = Crate(root)
        graph = {}
        for module, path in crate.files.items():
            files_checked += 1
            text = strip_comments_and_strings(open(path, encoding="utf-8").read())
            targets = set()
            spans = inline_modules(text)
            uses = [(offset, p) for offset, p, _ in use_paths(text, with_offsets=True)]
            for offset, segments in uses + inline_paths(text):
                target = crate.resolve(path, segments, inline=nesting(spans, offset))
                if target and target != path:
                    targets.add(target)
            graph[path] = targets
        for component in cycles(graph):
            rel = [os.path.relpath(f, ROOT) for f in component]
            problems.append(rel)
    for rel in problems:
        print("import cycle: " + " <-> ".join(rel))
        # Name the edges inside the cycle so the fix is obvious.
    if problems:
        print(f"{len(problems)} import cycle(s) in {files_checked} files")
        return 1
    print(f"no import cycles in {files_checked} files")
    return 0


if __name__ == "__main__":
    sys.exit(main())
