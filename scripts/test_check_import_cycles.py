#!/usr/bin/env python3
"""Tests of scripts/check-import-cycles.py: small crate trees in temporary folders, and the real
repository. Run: python3 scripts/test_check_import_cycles.py"""
import os
import subprocess
import sys
import tempfile
import textwrap
import unittest

HERE = os.path.dirname(os.path.abspath(__file__))
CHECKER = os.path.join(HERE, "check-import-cycles.py")
REPOSITORY = os.environ.get("CHECK_IMPORT_CYCLES_ROOT", os.path.dirname(HERE))

# The repository has (had) the circle warm/model.rs -> world/mod.rs -> world/instruments.rs ->
# warm/references/ablations.rs -> warm/model.rs in nodes/sim. Once it is fixed, flip this to
# False: test_repository then asserts that the checker finds no cycle at all.
# The last commit with the circle the old check did not see.
OLD_TREE = "4934514"


def check(files):
    """Runs the checker on a tree of {relative path: source}; returns (exit code, output)."""
    with tempfile.TemporaryDirectory() as root:
        for rel, text in files.items():
            path = os.path.join(root, rel)
            os.makedirs(os.path.dirname(path), exist_ok=True)
            with open(path, "w", encoding="utf-8") as f:
                f.write(textwrap.dedent(text).lstrip("\n"))
        run = subprocess.run([sys.executable, CHECKER, root], capture_output=True, text=True, timeout=60)
    if run.returncode not in (0, 1) or run.stderr:
        raise AssertionError(f"checker failed ({run.returncode}):\n{run.stderr}{run.stdout}")
    return run.returncode, run.stdout


def cycle_lines(output):
    return [line for line in output.splitlines() if line.startswith("import cycle: ")]


class Cycles(unittest.TestCase):
    def assert_cycle(self, files, *members, edges=()):
        """The checker fails, with one cycle made of exactly `members` (paths under src/), and
        prints every line of `edges`."""
        code, out = check(files)
        self.assertEqual(code, 1, out)
        expected = "import cycle: " + " <-> ".join(sorted("src/" + m for m in members))
        self.assertIn(expected, cycle_lines(out), out)
        for edge in edges:
            self.assertIn(edge, out.splitlines(), out)
        return out

    def assert_clean(self, files):
        code, out = check(files)
        self.assertEqual(code, 0, out)
        self.assertEqual(cycle_lines(out), [], out)
        self.assertRegex(out, r"^no import cycles in \d+ files$")

    # --- found ----------------------------------------------------------------------------

    def test_use_at_top_level(self):
        self.assert_cycle(
            {
                "src/lib.rs": "mod a;\nmod b;\n",
                "src/a.rs": "use crate::b::B;\npub struct A;\n",
                "src/b.rs": "use crate::a::A;\npub struct B;\n",
            },
            "a.rs",
            "b.rs",
            edges=["  src/a.rs:1 -> src/b.rs (use crate::b::B)", "  src/b.rs:1 -> src/a.rs (use crate::a::A)"],
        )

    def test_use_in_fn_body(self):
        self.assert_cycle(
            {
                "src/lib.rs": "mod a;\nmod b;\n",
                "src/a.rs": """
                    pub struct A;
                    pub fn f() {
                        let x = 1;
                        {
                            use crate::b::{helper, B};
                            helper(x);
                        }
                    }
                """,
                "src/b.rs": "use crate::a::A;\npub struct B;\npub fn helper(_: i32) {}\n",
            },
            "a.rs",
            "b.rs",
            edges=["  src/a.rs:5 -> src/b.rs (use crate::b::B)"],
        )

    def test_use_in_impl_block(self):
        self.assert_cycle(
            {
                "src/lib.rs": "mod a;\nmod b;\n",
                "src/a.rs": """
                    pub struct A;
                    impl A {
                        pub fn f(&self) -> usize {
                            use crate::b::B;
                            std::mem::size_of::<B>()
                        }
                    }
                """,
                "src/b.rs": "use crate::a::A;\npub struct B;\n",
            },
            "a.rs",
            "b.rs",
        )

    def test_inline_crate_path_in_struct_field(self):
        self.assert_cycle(
            {
                "src/lib.rs": "mod a;\nmod b;\n",
                "src/a.rs": "pub struct A<'a> {\n    b: &'a [crate::b::B],\n}\n",
                "src/b.rs": "pub struct B;\npub fn f(_: Vec<crate::a::A<'static>>) {}\n",
            },
            "a.rs",
            "b.rs",
            edges=["  src/a.rs:2 -> src/b.rs (crate::b::B)", "  src/b.rs:2 -> src/a.rs (crate::a::A)"],
        )

    def test_inline_super_and_self_paths(self):
        self.assert_cycle(
            {
                "src/lib.rs": "mod m;\n",
                "src/m/mod.rs": "mod x;\npub struct M;\npub fn f() -> self::x::X { self::x::X }\n",
                "src/m/x.rs": "pub struct X;\npub fn g(_: super::M) {}\n",
            },
            "m/mod.rs",
            "m/x.rs",
            edges=["  src/m/mod.rs:3 -> src/m/x.rs (self::x::X)", "  src/m/x.rs:2 -> src/m/mod.rs (super::M)"],
        )

    def test_inline_super_super_path(self):
        self.assert_cycle(
            {
                "src/lib.rs": "mod m;\npub struct Root;\nfn f() -> self::m::n::N { todo!() }\n",
                "src/m/mod.rs": "pub mod n;\n",
                "src/m/n.rs": "pub struct N;\nfn g(_: super::super::Root) {}\n",
            },
            "lib.rs",
            "m/n.rs",
            edges=["  src/m/n.rs:2 -> src/lib.rs (super::super::Root)"],
        )

    def test_child_module_headed_inline_path(self):
        self.assert_cycle(
            {
                "src/lib.rs": "mod world;\n",
                "src/world/mod.rs": "mod body;\npub struct World {\n    bodies: Vec<body::BodyState>,\n}\n",
                "src/world/body.rs": "pub struct BodyState;\nfn f(_: &crate::world::World) {}\n",
            },
            "world/mod.rs",
            "world/body.rs",
            edges=["  src/world/mod.rs:3 -> src/world/body.rs (body::BodyState)"],
        )

    def test_use_bound_module_and_alias(self):
        for use, path in (
            ("use crate::warm;", "warm::model::X"),
            ("use crate::warm as w;", "w::model::X"),
            ("use crate::{warm::{self as w}};", "w::model::X"),
        ):
            with self.subTest(use=use):
                self.assert_cycle(
                    {
                        "src/lib.rs": "mod a;\nmod warm;\n",
                        "src/a.rs": f"pub struct A;\npub fn f() {{\n    {use}\n    let _x: {path} = todo!();\n}}\n",
                        "src/warm/mod.rs": "pub mod model;\n",
                        "src/warm/model.rs": "pub struct X;\nfn g(_: crate::a::A) {}\n",
                    },
                    "a.rs",
                    "warm/model.rs",
                    edges=[f"  src/a.rs:4 -> src/warm/model.rs ({path})"],
                )

    def test_pub_use_facade(self):
        """The sim circle: a.rs names crate::m::Item, which m/mod.rs re-exports from m/item.rs;
        m/mod.rs privately uses m/other.rs, and m/other.rs uses a.rs."""
        self.assert_cycle(
            {
                "src/lib.rs": "mod a;\nmod m;\n",
                "src/a.rs": "pub struct A<'a> {\n    items: &'a [crate::m::Item],\n}\n",
                "src/m/mod.rs": "mod item;\nmod other;\n\npub use item::Item;\n\nuse other::{Other};\n",
                "src/m/item.rs": "pub struct Item;\n",
                "src/m/other.rs": "pub struct Other;\npub fn f() {\n    use crate::a::A;\n}\n",
            },
            "a.rs",
            "m/mod.rs",
            "m/other.rs",
            edges=[
                "  src/a.rs:2 -> src/m/mod.rs (crate::m::Item)",
                "  src/m/mod.rs:6 -> src/m/other.rs (use other::Other)",
                "  src/m/other.rs:3 -> src/a.rs (use crate::a::A)",
            ],
        )

    def test_reexport_chain(self):
        # crate::Item -> lib.rs `pub use m::Item` -> m/mod.rs `pub use item::Item` -> m/item.rs
        self.assert_cycle(
            {
                "src/lib.rs": "mod a;\nmod m;\npub use m::Item;\n",
                "src/a.rs": "pub struct A;\nfn f(_: crate::Item) {}\n",
                "src/m/mod.rs": "mod item;\npub use item::Item;\n",
                "src/m/item.rs": "pub struct Item;\nfn g(_: crate::a::A) {}\n",
            },
            "a.rs",
            "m/item.rs",
            edges=["  src/a.rs:2 -> src/m/item.rs (crate::Item)", "  src/m/item.rs:2 -> src/a.rs (crate::a::A)"],
        )
        # The path also depends on both re-exporters (they only publish: no edge back).
        code, out = check(
            {
                "src/lib.rs": "mod a;\nmod m;\npub use m::Item;\nfn f(_: a::A) {}\n",
                "src/a.rs": "pub struct A;\nfn f(_: crate::Item) {}\n",
                "src/m/mod.rs": "mod item;\npub use item::Item;\n",
                "src/m/item.rs": "pub struct Item;\n",
            }
        )
        self.assertIn("import cycle: src/a.rs <-> src/lib.rs", cycle_lines(out), out)

    def test_glob_reexport(self):
        self.assert_cycle(
            {
                "src/lib.rs": "mod a;\nmod m;\n",
                "src/a.rs": "pub struct A;\nfn f(_: crate::m::Item) {}\n",
                "src/m/mod.rs": "mod item;\npub use item::*;\n",
                "src/m/item.rs": "use crate::a::A;\npub struct Item;\n",
            },
            "a.rs",
            "m/item.rs",
            edges=["  src/a.rs:2 -> src/m/item.rs (crate::m::Item)"],
        )

    def test_use_tree_forms(self):
        """Nested groups, `self` in a group, aliases and globs each import; a leading `::` names
        another crate; a re-export of any visibility (`pub(crate)`, `pub(in path)`) publishes and
        imports nothing of its own."""
        files = {
            "src/lib.rs": "mod a;\nmod b;\nmod c;\nmod d;\nmod e;\nmod f;\nmod g;\nmod h;\n",
            "src/a.rs": """
                use crate::{b::{B}, c::{self}};
                use crate::d::D as Dee;
                use crate::e::*;
                use ::f::F;
                pub(in crate) use crate::g::G;
                use crate::h::{
                    H,
                };
                pub struct A;
            """,
        }
        for name in "bcdefgh":
            files[f"src/{name}.rs"] = f"use crate::a::A;\npub struct {name.upper()};\n"
        self.assert_cycle(files, "a.rs", "b.rs", "c.rs", "d.rs", "e.rs", "h.rs",
                          edges=["  src/a.rs:7 -> src/h.rs (use crate::h::H)"])

    def test_path_attribute(self):
        self.assert_cycle(
            {
                "src/lib.rs": '#[path = "elsewhere/thing.rs"]\nmod thing;\npub struct Root;\nfn f(_: thing::T) {}\n',
                "src/elsewhere/thing.rs": "pub struct T;\nfn g(_: crate::Root) {}\n",
            },
            "elsewhere/thing.rs",
            "lib.rs",
        )

    # --- not found --------------------------------------------------------------------------

    def test_no_cycle(self):
        self.assert_clean(
            {
                "src/lib.rs": "mod a;\nmod b;\npub use a::A;\n",
                "src/a.rs": "use crate::b::B;\npub struct A(B);\nfn f() -> b_alias::B { todo!() }\nuse crate::b as b_alias;\n",
                "src/b.rs": "pub struct B;\n",
            }
        )

    def test_comments_strings_raw_strings_chars(self):
        self.assert_clean(
            {
                "src/lib.rs": "mod a;\nmod b;\n",
                "src/a.rs": "use crate::b::B;\npub struct A;\n",
                "src/b.rs": r'''
                    //! Docs naming [`crate::a::A`] and `use crate::a::A;`.
                    // use crate::a::A;
                    /* crate::a::A /* nested */ use crate::a::A; */
                    /// See crate::a::A.
                    pub struct B;
                    pub fn f<'a>(x: &'a str) -> (&'a str, char, char, char, &'static str) {
                        let s = "use crate::a::A; \" crate::a::A";
                        let r = r#"use crate::a::A; "quoted" { "#;
                        let r2 = br##"crate::a::A"#"##;
                        let q = '"';
                        let o = '{';
                        let e = '\'';
                        'outer: loop { break 'outer; }
                        (x, q, o, e, s)
                    }
                    pub fn g() -> &'static str { "}" }
                ''',
            }
        )

    def test_lifetimes_do_not_hide_paths(self):
        self.assert_cycle(
            {
                "src/lib.rs": "mod a;\nmod b;\n",
                "src/a.rs": "use crate::b::B;\npub struct A;\n",
                "src/b.rs": "pub struct B;\npub fn f<'a>(x: &'a str, y: &'a crate::a::A) -> &'a str { let _ = '{'; x }\n",
            },
            "a.rs",
            "b.rs",
            edges=["  src/b.rs:2 -> src/a.rs (crate::a::A)"],
        )

    def test_mod_declaration_is_no_import(self):
        self.assert_clean(
            {
                "src/lib.rs": "mod a;\n",
                "src/a.rs": "pub mod b;\npub(crate) mod c;\npub struct A;\n",
                "src/a/b.rs": "use crate::a::A;\nfn f(_: super::A) {}\n",
                "src/a/c.rs": "use super::b;\n",
            }
        )

    def test_other_crates_and_std(self):
        self.assert_clean(
            {
                "src/lib.rs": "mod a;\nmod fmt;\nmod serde;\n",
                "src/a.rs": """
                    use std::fmt::Write;
                    use ::serde::Serialize;
                    use core::fmt::{self, Display};
                    pub struct A;
                    impl std::fmt::Debug for A {
                        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result { Ok(()) }
                    }
                    fn g<T: ::serde::Serialize>(_: T) -> Vec<std::fmt::Error> { Vec::<std::fmt::Error>::new() }
                """,
                "src/fmt.rs": "use crate::a::A;\n",
                "src/serde.rs": "use crate::a::A;\n",
            }
        )

    def test_inline_tests_module_super_is_the_file(self):
        self.assert_clean(
            {
                "src/lib.rs": "mod a;\npub use a::A;\n",
                "src/a.rs": """
                    pub struct A;
                    #[cfg(test)]
                    mod tests {
                        use super::*;
                        mod deeper {
                            use super::super::A;
                        }
                        #[test]
                        fn t() {
                            let _ = super::A;
                            let _: A = A;
                        }
                    }
                """,
            }
        )

    # --- the real repository ----------------------------------------------------------------

    def test_repository(self):
        """The workspace as it is: no circle."""
        run = subprocess.run([sys.executable, CHECKER, REPOSITORY], capture_output=True, text=True, timeout=60)
        self.assertEqual(run.stderr, "")
        self.assertEqual(cycle_lines(run.stdout), [], run.stdout)
        self.assertEqual(run.returncode, 0, run.stdout)

    def test_the_circle_the_old_check_missed(self):
        """The tree of commit 4934514 (before the circle was broken): warm/model.rs named
        `crate::world::BodyState` (re-exported by world/mod.rs), world/mod.rs used
        world/instruments.rs, which used warm/references/ablations.rs inside a function, which
        used warm/model.rs. The old check said "no import cycles in 126 files"."""
        if not os.path.isdir(os.path.join(REPOSITORY, ".git")):
            self.skipTest("not a git checkout")
        with tempfile.TemporaryDirectory() as root:
            archive = subprocess.run(
                ["git", "-C", REPOSITORY, "archive", OLD_TREE, "nodes/sim"], capture_output=True, timeout=60
            )
            if archive.returncode != 0:
                self.skipTest(f"commit {OLD_TREE} is not in this clone: {archive.stderr.decode()}")
            subprocess.run(["tar", "-x", "-C", root], input=archive.stdout, check=True, timeout=60)
            run = subprocess.run([sys.executable, CHECKER, root], capture_output=True, text=True, timeout=60)
        self.assertEqual(run.returncode, 1, run.stdout)
        circle = [c for c in cycle_lines(run.stdout) if "nodes/sim/src/warm/model.rs" in c.split()]
        self.assertTrue(circle, run.stdout)
        for member in ("world/mod.rs", "world/instruments.rs", "warm/references/ablations.rs"):
            self.assertIn("nodes/sim/src/" + member, circle[0].split(), run.stdout)
        self.assertIn("nodes/sim/src/warm/model.rs:88 -> nodes/sim/src/world/mod.rs (crate::world::BodyState)", run.stdout)


if __name__ == "__main__":
    unittest.main()
