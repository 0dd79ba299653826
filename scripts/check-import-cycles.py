#!/usr/bin/env python3
"""Fails when a source file imports, directly or through others, a module that imports it back.

Within each crate of the workspace (every `src/lib.rs`, `src/main.rs`, `src/bin/*.rs` and
`src/bin/*/main.rs`), a file imports every module file that one of its paths depends on:

* `use` trees at any depth (module level, fn bodies, blocks, inline `mod x { }`), with groups,
  nested groups, `self` in groups, aliases, globs, any visibility; and inline paths in types and
  expressions (`crate::a::B`, `super::x`, `self::y`, `child::z`, `alias::z` where a `use` binds
  `alias` to a module, `$crate::a` in macros).
* A path resolves the way rustc resolves it, name by name through the module tree. Naming a child
  module (`crate::a::b::Item`) is free: the path depends on the file where it ends (`a/b.rs`).
  Going through a name that a module imports (`pub use body::BodyState;` in `world/mod.rs`, or a
  glob `pub use x::*`) depends on that module's file AND on where the name comes from, following
  chains of re-exports. A file's own private `use` is an import of what it names; its own
  `pub use` only publishes (a crate root re-exporting its children while they use its `Error`
  is no circle), but every path through it depends on it and on the source.
* `mod x;` (with or without `#[path]`) only declares a child: no import. Cross-crate paths cannot
  form cycles (cargo forbids them) and are not followed; neither are std, the prelude and locals.
* Comments, string/char literals (raw strings too) are blanked before scanning.

Each cycle (a strongly connected component of the file graph) is printed with the edges inside
it and the line of the first path that makes each edge.

Usage: scripts/check-import-cycles.py [ROOT]   (ROOT: the workspace, default: this repository)
"""
import bisect
import os
import re
import sys

SKIP = {"target", ".git", "fuzz", "node_modules"}
MAX_DEPTH = 24  # bound on chains of re-exports / aliases

# --------------------------------------------------------------------------------------------
# Lexing: blank comments and literals, keeping every offset (and newline) where it was.

LEX = re.compile(r"""//|/\*|(?<![\w])(?:b|c)?r(#*)"|"|'""")
NOT_NEWLINE = re.compile(r"[^\n]")
COMMENT_EDGE = re.compile(r"/\*|\*/")


def blank(text):
    """`text` with comments, string and char literals replaced by spaces (newlines kept, quotes of
    plain strings kept), so that offsets and line numbers still match the source. Lifetimes and
    labels (`'a`, `'static`, `'outer:`) are left alone."""
    out, done, n, i = [], 0, len(text), 0

    def wipe(a, b):
        nonlocal done
        out.append(text[done:a])
        out.append(NOT_NEWLINE.sub(" ", text[a:b]))
        done = b

    while True:
        m = LEX.search(text, i)
        if not m:
            break
        i, tok = m.start(), m.group(0)
        if tok == "//":
            j = text.find("\n", i)
            j = n if j < 0 else j
            wipe(i, j)
        elif tok == "/*":  # block comments nest in Rust
            depth, j = 1, i + 2
            while depth:
                k = COMMENT_EDGE.search(text, j)
                if not k:
                    j = n
                    break
                depth += 1 if k.group(0) == "/*" else -1
                j = k.end()
            wipe(i, j)
        elif tok == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            wipe(i + 1, j)
            j += 1
        elif tok == "'":
            if i + 1 < n and text[i + 1] == "\\":  # '\n', '\'', '\\', '\u{..}'
                j = text.find("'", i + 3)
                j = n if j < 0 else j + 1
                wipe(i, j)
            elif i + 2 < n and text[i + 2] == "'" and text[i + 1] != "\n":  # 'x', '{', '"'
                j = i + 3
                wipe(i, j)
            else:
                j = i + 1  # a lifetime or a label
        else:  # a raw string: r"..", r#".."#, br"..", cr".."
            close = '"' + m.group(1)
            j = text.find(close, m.end())
            j = n if j < 0 else j + len(close)
            wipe(i, j)
        i = j
    out.append(text[done:])
    return "".join(out)


# --------------------------------------------------------------------------------------------
# One file's structure: braces, inline modules, `mod` declarations, `use` trees, items, paths.

IDENT = r"(?:r#)?[A-Za-z_]\w*"
MOD_DECL = re.compile(r"\bmod\s+(" + IDENT + r")\s*([;{])")
USE_KW = re.compile(r"(?<![\w$#])use\b(?!\s*<)")
VIS_BEFORE = re.compile(r"\bpub\s*(?:\([^()]*\))?\s*$")
VIS_RESTRICTED = re.compile(r"\bpub\s*\(\s*in\b[^)]*\)")
ITEM = re.compile(
    r"\b(?:struct|enum|union|trait|type|fn|static|const)\s+"
    r"(?:(?:mut|const|unsafe|async|extern|fn|ref)\s+)*(" + IDENT + r")"
)
INLINE_PATH = re.compile(
    r"(?<![\w$:'#])(::\s*)?(\$?" + IDENT + r")((?:\s*::\s*" + IDENT + r")+)"
)
USE_TOKEN = re.compile(r"::|[{},*]|\$?" + IDENT + r"|\S")
PATH_ATTR = re.compile(r'#\s*\[\s*path\s*=\s*"')


def ident(name):
    return name[2:] if name.startswith("r#") else name


class Leaf:
    """One path a `use` tree names: `segments` (a module path for a glob), the name it binds
    (None for globs and `as _`), where it is written."""

    __slots__ = ("segments", "glob", "binds", "offset", "public")

    def __init__(self, segments, glob, binds, offset):
        self.segments, self.glob, self.binds, self.offset = segments, glob, binds, offset
        self.public = False

    def text(self):
        path = "::".join(self.segments) + ("::*" if self.glob else "")
        return ("pub use " if self.public else "use ") + path


def parse_use_tree(tree, base):
    """The leaves of a `use` tree (the text between `use` and `;`; `base`: its offset)."""
    tokens = [(m.group(0), base + m.start()) for m in USE_TOKEN.finditer(tree)]
    leaves = []

    def parse(i, prefix):
        segments = list(prefix)
        if tokens[i][0] == "::":  # `use ::x` / `{::x}`: another crate
            segments.append("")
            i += 1
        while True:
            tok, off = tokens[i]
            if tok == "{":
                i += 1
                while tokens[i][0] != "}":
                    i = parse(i, segments)
                    if tokens[i][0] == ",":
                        i += 1
                return i + 1
            if tok == "*":
                leaves.append(Leaf(segments, True, None, off))
                return i + 1
            if not re.fullmatch(r"\$?" + IDENT, tok):
                raise ValueError(tok)
            segments = segments + [ident(tok)]
            i += 1
            if i < len(tokens) and tokens[i][0] == "::":
                i += 1
                continue
            binds = segments[-1]
            if i < len(tokens) and tokens[i][0] == "as":
                binds = ident(tokens[i + 1][0])
                i += 2
            if segments[-1] == "self" and len(segments) > 1:  # `a::{self}` binds `a`
                segments = segments[:-1]
                if binds == "self":
                    binds = segments[-1]
            leaves.append(Leaf(segments, False, None if binds == "_" else binds, off))
            return i

    try:
        parse(0, [])
    except (IndexError, ValueError):
        pass  # a macro's `use $path;` or something we cannot read: keep what was parsed
    return leaves


class Span:
    __slots__ = ("open", "close", "parent", "module")

    def __init__(self, open_, parent):
        self.open, self.close, self.parent, self.module = open_, None, parent, None


class Source:
    """The parsed text of one file (shared by every crate that includes the file)."""

    def __init__(self, path):
        self.path = path
        self.text = open(path, encoding="utf-8").read()
        code = blank(self.text)
        self.code = code
        self.line_starts = [0] + [m.end() for m in re.finditer("\n", code)]
        # Braces: spans, and the innermost span at every offset (by change points).
        self.spans, self.change_at, self.change_to = [], [0], [-1]
        stack = []
        for m in re.finditer(r"[{}]", code):
            if m.group(0) == "{":
                self.spans.append(Span(m.start(), stack[-1] if stack else -1))
                stack.append(len(self.spans) - 1)
                self.change_at.append(m.start() + 1)
                self.change_to.append(stack[-1])
            elif stack:
                self.spans[stack.pop()].close = m.start()
                self.change_at.append(m.start())
                self.change_to.append(stack[-1] if stack else -1)
        for s in self.spans:
            if s.close is None:
                s.close = len(code)
        open_to_span = {s.open: k for k, s in enumerate(self.spans)}
        # Modules: inline bodies (`mod x {`) and declarations (`mod x;`, with any `#[path]`).
        self.inline = []  # (span, name)
        self.decls = []  # (offset, name, path attribute or None)
        for m in MOD_DECL.finditer(code):
            name = ident(m.group(1))
            if m.group(2) == "{":
                span = open_to_span.get(m.end() - 1)
                if span is not None:
                    self.spans[span].module = name
                    self.inline.append((span, name))
            else:
                self.decls.append((m.start(), name, self.path_attribute(m.start())))
        # `use` declarations: their leaves, and the spans they cover (no inline paths there).
        self.uses = []  # (innermost span, leaves)
        hidden = [(m.start(), m.end()) for m in VIS_RESTRICTED.finditer(code)]
        for m in USE_KW.finditer(code):
            before = code[max(0, m.start() - 200) : m.start()]
            vis = VIS_BEFORE.search(before)
            if vis:
                before = before[: vis.start()]
            prev = before.rstrip()[-1:]
            if prev not in ("", ";", "{", "}", "]"):
                continue  # `use` in some other role
            end = code.find(";", m.end())
            end = len(code) if end < 0 else end
            leaves = parse_use_tree(code[m.end() : end], m.end())
            for leaf in leaves:
                leaf.public = bool(vis) and not re.fullmatch(r"pub\s*\(\s*self\s*\)\s*", vis.group(0))
            self.uses.append((self.innermost(m.start()), leaves))
            hidden.append((m.start(), end))
        # Items defined at some level (struct, enum, fn, ...): (innermost span, name).
        self.items = [(self.innermost(m.start()), ident(m.group(1))) for m in ITEM.finditer(code)]
        # Inline paths outside `use` declarations and `pub(in ...)`.
        masked = list(code)
        for a, b in hidden:
            masked[a:b] = " " * (b - a)
        masked = "".join(masked)
        self.paths = []  # (offset, segments, text)
        for m in INLINE_PATH.finditer(masked):
            if m.group(1):
                continue  # `::x::y`: another crate
            segments = [m.group(2)] + [ident(s.strip()) for s in m.group(3).split("::")[1:]]
            segments[0] = ident(segments[0])
            self.paths.append((m.start(2), segments, "::".join(segments)))

    def path_attribute(self, offset):
        """The `#[path = "..."]` among the attributes right before a `mod` at `offset`."""
        code, i = self.code, offset
        vis = VIS_BEFORE.search(code[max(0, offset - 100) : offset])
        if vis:
            i = max(0, offset - 100) + vis.start()
        while True:
            j = i
            while j > 0 and code[j - 1].isspace():
                j -= 1
            if j == 0 or code[j - 1] != "]":
                return None
            depth, k = 0, j - 1
            while k >= 0:  # back to the matching `#[`
                if code[k] == "]":
                    depth += 1
                elif code[k] == "[":
                    depth -= 1
                    if depth == 0:
                        break
                k -= 1
            start = code.rfind("#", 0, k)
            if start < 0:
                return None
            m = PATH_ATTR.match(code, start)
            if m and m.end() <= j:
                close = code.find('"', m.end())
                return self.text[m.end() : close]
            i = start

    def innermost(self, offset):
        return self.change_to[bisect.bisect_right(self.change_at, offset) - 1]

    def line(self, offset):
        return bisect.bisect_right(self.line_starts, offset)


SOURCES = {}


def source(path):
    if path not in SOURCES:
        SOURCES[path] = Source(path)
    return SOURCES[path]


# --------------------------------------------------------------------------------------------
# A crate: its module tree, name resolution through it.


class Scope:
    """A module (file or inline) or a block with `use` declarations: the names it binds."""

    def __init__(self, module=None):
        self.module = module  # the Module a block belongs to (None: this is a module)
        self.bindings = {}  # name -> [Leaf]
        self.globs = []  # [Leaf]


class Module(Scope):
    def __init__(self, path, file, parent, child_dir):
        super().__init__()
        self.path, self.file, self.parent, self.child_dir = path, file, parent, child_dir
        self.children = {}
        self.items = set()


class Crate:
    def __init__(self, root_file):
        self.files = {}  # file -> its Module
        self.blocks = {}  # (file, span) -> Scope
        self.module_at = {}  # (file, span) -> Module (for module spans)
        self.active = set()  # (scope, name) lookups under way
        self.root = self.load(root_file, (), None, os.path.dirname(root_file))

    def load(self, path, modpath, parent, child_dir):
        src = source(path)
        module = Module(modpath, path, parent, child_dir)
        self.files[path] = module
        self.module_at[(path, -1)] = module
        # Inline modules, outermost first (spans are in order of their opening brace).
        for span, name in src.inline:
            owner = self.module_of(src, src.spans[span].parent)
            inner = Module(owner.path + (name,), path, owner, os.path.join(owner.child_dir, name))
            owner.children[name] = inner
            self.module_at[(path, span)] = inner
        for offset, name, attr in src.decls:
            owner = self.module_of(src, src.innermost(offset))
            if attr is not None:
                base = os.path.dirname(path) if owner is module else owner.child_dir
                candidates = [os.path.normpath(os.path.join(base, attr))]
            else:
                candidates = [os.path.join(owner.child_dir, name + ".rs"), os.path.join(owner.child_dir, name, "mod.rs")]
            for file in candidates:
                if os.path.isfile(file) and file not in self.files:
                    mod_rs = attr is not None or os.path.basename(file) == "mod.rs"
                    sub_dir = os.path.dirname(file) if mod_rs else file[:-3]
                    owner.children[name] = self.load(file, owner.path + (name,), owner, sub_dir)
                    break
        for span, leaves in src.uses:
            scope = self.scope_at(src, span)
            for leaf in leaves:
                if leaf.glob:
                    scope.globs.append(leaf)
                elif leaf.binds:
                    scope.bindings.setdefault(leaf.binds, []).append(leaf)
        for span, name in src.items:
            if span == -1 or src.spans[span].module is not None:
                self.module_of(src, span).items.add(name)
        return module

    def module_of(self, src, span):
        """The module (file or inline) that a brace span (-1: file level) stands in."""
        while span != -1 and src.spans[span].module is None:
            span = src.spans[span].parent
        return self.module_at[(src.path, span)]

    def scope_at(self, src, span):
        """The scope whose `use` declarations live directly in `span`."""
        if span == -1 or src.spans[span].module is not None:
            return self.module_at[(src.path, span)]
        key = (src.path, span)
        if key not in self.blocks:
            self.blocks[key] = Scope(self.module_of(src, span))
        return self.blocks[key]

    def chain(self, src, offset):
        """The module at `offset` and the block scopes around it, innermost first."""
        span, blocks = src.innermost(offset), []
        while span != -1 and src.spans[span].module is None:
            if (src.path, span) in self.blocks:
                blocks.append(self.blocks[(src.path, span)])
            span = src.spans[span].parent
        return self.module_at[(src.path, span)], blocks

    # Resolution. An entity is (module or None, file or None, deps): a Module when the path
    # names a module, else the file of the item (None outside the crate); deps: the files of
    # the modules whose imports the path went through.

    def lookup(self, scope, name, depth, outer=()):
        """`name` in a scope's namespace (`outer`: the block scopes around a block)."""
        key = (id(scope), name)
        if depth > MAX_DEPTH or key in self.active:
            return None  # a chain of imports that leads back to itself
        self.active.add(key)
        try:
            return self.lookup_in(scope, name, depth, outer)
        finally:
            self.active.discard(key)

    def lookup_in(self, scope, name, depth, outer):
        if isinstance(scope, Module):
            if name in scope.children:
                return scope.children[name], scope.children[name].file, frozenset()
            if name in scope.items:
                return None, scope.file, frozenset()
            module, blocks = scope, []
        else:
            module, blocks = scope.module, list(outer)
        here = frozenset([module.file])
        for leaf in scope.bindings.get(name, ()):
            found = self.resolve(module, leaf.segments, blocks, depth + 1)
            if found is None:
                return None, None, here  # a re-export of something outside the crate
            return found[0], found[1], found[2] | here
        for leaf in scope.globs:
            source_ = self.resolve(module, leaf.segments, blocks, depth + 1)
            if source_ and source_[0] is not None and source_[0] is not scope:
                found = self.lookup(source_[0], name, depth + 1)
                if found:
                    return found[0], found[1], found[2] | source_[2] | here
        return None

    def resolve(self, module, segments, blocks, depth=0):
        """What a path written in `module` (inside `blocks`) names, or None when it leaves the
        crate (another crate, std, the prelude, a local or generic name)."""
        if not segments or depth > MAX_DEPTH:
            return None
        head, deps = segments[0], frozenset()
        if head in ("crate", "$crate"):
            current, rest = self.root, segments[1:]
        elif head in ("self", "super"):
            current, i = module, 0
            while i < len(segments) and segments[i] in ("self", "super"):
                if segments[i] == "super":
                    current = current.parent
                    if current is None:
                        return None
                i += 1
            rest = segments[i:]
        elif head == "":
            return None
        else:
            found = None
            for k, block in enumerate(blocks):
                found = self.lookup(block, head, depth, blocks[k + 1 :])
                if found:
                    break
            found = found or self.lookup(module, head, depth)
            if found is None:
                return None
            current, deps, rest = found[0], found[2], segments[1:]
            if current is None:
                return found
        for name in rest:
            found = self.lookup(current, name, depth + 1)
            if found is None:
                return None, current.file, deps  # an item we cannot see (enum variant, macro...)
            deps = deps | found[2]
            if found[0] is None:
                return None, found[1], deps
            current = found[0]
        return current, current.file, deps

    def imports(self, path):
        """{imported file: [(line, path text)]} of one file."""
        src = source(path)
        edges = {}

        def add(offset, segments, text):
            module, blocks = self.chain(src, offset)
            found = self.resolve(module, segments, blocks)
            if found is None:
                return
            targets = set(found[2])
            if found[1]:
                targets.add(found[1])
            for target in targets - {path}:
                edges.setdefault(target, []).append((src.line(offset), text))

        for _, leaves in src.uses:
            for leaf in leaves:
                # A re-export publishes (the crate's face: `lib.rs` re-exports `Error` that its
                # children use); whoever names the item through it depends on both files.
                if not leaf.public:
                    add(leaf.offset, leaf.segments, leaf.text())
        for offset, segments, text in src.paths:
            add(offset, segments, text)
        for sites in edges.values():
            sites.sort()
        return edges


# --------------------------------------------------------------------------------------------


def crate_roots(root):
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = sorted(d for d in dirnames if d not in SKIP and not d.startswith("."))
        if os.path.basename(dirpath) == "src":
            for name in ("lib.rs", "main.rs"):
                if name in filenames:
                    yield os.path.join(dirpath, name)
            bin_dir = os.path.join(dirpath, "bin")
            if os.path.isdir(bin_dir):
                for f in sorted(os.listdir(bin_dir)):
                    full = os.path.join(bin_dir, f)
                    if f.endswith(".rs") and os.path.isfile(full):
                        yield full
                    elif os.path.isfile(os.path.join(full, "main.rs")):
                        yield os.path.join(full, "main.rs")


def cycles(graph):
    """Each strongly connected component of more than one file, sorted (Tarjan, iterative)."""
    index, low, on, stack, found = {}, {}, set(), [], []
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph.get(start, ()))))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on.add(start)
        while work:
            v, successors = work[-1]
            advanced = False
            for w in successors:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph.get(w, ())))))
                    advanced = True
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            if advanced:
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
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
    return found


def main(argv):
    root = os.path.abspath(argv[1] if len(argv) > 1 else os.path.join(os.path.dirname(__file__), ".."))
    rel = lambda f: os.path.relpath(f, root)
    reports, seen, files_checked = [], set(), 0
    for crate_root in crate_roots(root):
        crate = Crate(crate_root)
        graph = {}
        for path in crate.files:
            files_checked += 1
            graph[path] = crate.imports(path)
        for component in cycles(graph):
            if tuple(component) in seen:
                continue
            seen.add(tuple(component))
            members = set(component)
            lines = ["import cycle: " + " <-> ".join(rel(f) for f in component)]
            for a in component:
                for b in sorted(set(graph[a]) & members):
                    sites = graph[a][b]
                    line, text = sites[0]
                    more = sorted({l for l, _ in sites[1:]} - {line})
                    also = f", also line{'s' if len(more) > 1 else ''} {', '.join(map(str, more))}" if more else ""
                    lines.append(f"  {rel(a)}:{line} -> {rel(b)} ({text}{also})")
            reports.append("\n".join(lines))
    for report in reports:
        print(report)
    if reports:
        print(f"{len(reports)} import cycle(s) in {files_checked} files")
        return 1
    print(f"no import cycles in {files_checked} files")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
