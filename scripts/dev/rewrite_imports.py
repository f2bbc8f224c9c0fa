"""Rewrite imports and dotted references after a move, from a rename map (scripts/dev/rename_map.txt).

    python scripts/dev/rewrite_imports.py [--map scripts/dev/rename_map.txt] PATH...   # files or folders, in place

`from OLD import a, b` becomes one import per module the names now live in (a name moved alone, `OLD:name NEW`,
goes where the map says; the rest follow the module); `from PKG import mod` of a moved module becomes
`from NEWPKG import newmod as mod` (the local name kept); dotted references (`OLD.name` in docstrings, strings, docs)
are renamed, longest first. Another branch made before the move is rewritten by running this on its tree.
"""
from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

SUFFIXES = {".py", ".md", ".toml", ".spec", ".txt", ".cfg", ".ini", ".yml", ".yaml", ".json", ".sh"}


def read_map(path: Path) -> tuple[dict[str, str], dict[tuple[str, str], str]]:
    modules: dict[str, str] = {}
    names: dict[tuple[str, str], str] = {}
    for line in path.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        old, new = line.split()
        if ":" in old:
            mod, name = old.split(":")
            names[(mod, name)] = new
        else:
            modules[old] = new
    return modules, names


FROM_IMPORT = re.compile(r"^(?P<indent>[ \t]*)from (?P<mod>[\w.]+) import (?P<body>\([^)]*\)|[^\n]*?)(?P<comment>[ \t]*#[^\n]*)?$", re.M)


def split_names(body: str) -> list[str]:
    body = body.strip()
    if body.startswith("("):
        body = body[1:-1]
    body = re.sub(r"#[^\n]*", "", body)
    return [n.strip() for n in body.replace("\n", " ").split(",") if n.strip()]


def rewrite_from(m: re.Match, modules: dict[str, str], names: dict[tuple[str, str], str]) -> str:
    indent, mod, body = m.group("indent"), m.group("mod"), m.group("body")
    comment = m.group("comment") or ""
    moved_names = {n for (mm, n) in names if mm == mod}
    subs = {f"{mod}.{n.split(' as ')[0].strip()}" for n in split_names(body)}
    if mod not in modules and not moved_names and not (subs & modules.keys()):
        return m.group(0)
    groups: dict[str, list[str]] = {}
    lines: list[str] = []
    for item in split_names(body):
        name = item.split(" as ")[0].strip()
        alias = item.split(" as ")[1].strip() if " as " in item else None
        if (mod, name) in names:
            target = names[(mod, name)]
        elif f"{mod}.{name}" in modules:  # `from pkg import module` of a moved module
            new = modules[f"{mod}.{name}"]
            pkg, _, leaf = new.rpartition(".")
            local = alias or name
            lines.append(f"{indent}from {pkg} import {leaf}" + ("" if leaf == local else f" as {local}"))
            continue
        else:
            target = modules.get(mod, mod)
        groups.setdefault(target, []).append(item)
    for target, items in groups.items():
        text = f"{indent}from {target} import {', '.join(items)}"
        if len(text) > 140:
            text = f"{indent}from {target} import (\n" + "".join(f"{indent}    {i},\n" for i in items) + f"{indent})"
        lines.append(text)
    if lines and comment:
        lines[0] += comment
    return "\n".join(lines)


def rewrite_dotted(text: str, modules: dict[str, str], names: dict[tuple[str, str], str]) -> str:
    pairs = [(f"{m}.{n}", f"{t}.{n}") for (m, n), t in names.items()] + list(modules.items())
    pairs.sort(key=lambda p: -len(p[0]))
    pattern = re.compile(r"(?<![\w.])(" + "|".join(re.escape(o) for o, _ in pairs) + r")(?![\w])")
    table = dict(pairs)
    new_modules = set(modules.values())

    def sub(m: re.Match) -> str:
        after = re.match(r"\.(\w+)", text[m.end():])
        if after and f"{m.group(1)}.{after.group(1)}" in new_modules:  # already the new path (`pkg` became `pkg.sub`)
            return m.group(1)
        if any(v.startswith(m.group(1) + ".") for v in new_modules):
            return m.group(1)  # the old module is a package now: `from pkg import module` is `rewrite_from`'s, a bare name stays
        return table[m.group(1)]

    return pattern.sub(sub, text)


def rewrite_file(path: Path, modules: dict[str, str], names: dict[tuple[str, str], str]) -> bool:
    text = path.read_text()
    new = text
    if path.suffix == ".py":
        new = FROM_IMPORT.sub(lambda m: rewrite_from(m, modules, names), new)
        for old, target in sorted(modules.items(), key=lambda p: -len(p[0])):  # `import old.mod [as x]`
            new = re.sub(rf"^(\s*)import {re.escape(old)}(?![\w.])", rf"\1import {target}", new, flags=re.M)
    new = rewrite_dotted(new, modules, names)
    new = re.sub(r"(?<![\w.])(x2video(?:/\w+)*)/(\w+)\.py", lambda m: _path(m, modules), new) if path.suffix != ".py" else new
    if new != text:
        path.write_text(new)
        return True
    return False


def _path(m: re.Match, modules: dict[str, str]) -> str:
    dotted = (m.group(1) + "/" + m.group(2)).replace("/", ".")
    target = modules.get(dotted)
    return target.replace(".", "/") + ".py" if target else m.group(0)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--map", type=Path, default=Path(__file__).with_name("rename_map.txt"))
    ap.add_argument("paths", nargs="+", type=Path)
    args = ap.parse_args(argv)
    modules, names = read_map(args.map)
    changed = 0
    for root in args.paths:
        files = [root] if root.is_file() else [p for p in root.rglob("*") if p.suffix in SUFFIXES and ".git" not in p.parts
                                                and ".venv" not in p.parts and p.is_file()]
        for p in files:
            if p.resolve() == args.map.resolve():
                continue
            changed += rewrite_file(p, modules, names)
    print(f"rewrote {changed} file(s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
