"""Counts of how the configuration reads (issue #21's acceptance): config fields, fields that
default to None, places that define a profile, CLI flags, `# fmt: skip`, long lines, long
docstrings.

    python scripts/config_census.py            # Markdown table on stdout
    python scripts/config_census.py --json     # the same as JSON
"""

from __future__ import annotations

import ast
import json
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LIBRARY = ("aed_tasks", "aed_models", "aed_eval")
COMMANDS = (
    "collect",
    "train-policy",
    "train-detector",
    "rollout",
    "calibrate",
    "evaluate",
    "report",
    "demo",
    "monitor",
    "render",
)
PROFILE_TABLE = re.compile(r"^[A-Z_]*(PROFILES|MINI|PAPER)[A-Z_]*\s*(:[^=]*)?=", re.MULTILINE)
PROFILE_BRANCH = re.compile(
    r"profile\s*==\s*[\"'](mini|paper|demo)[\"']|def (for_profile|preset)\b"
)
LINE_LIMIT = 100


def python_files(packages: tuple[str, ...]) -> list[Path]:
    return sorted(p for pkg in packages for p in (ROOT / pkg).rglob("*.py"))


def is_dataclass(node: ast.ClassDef) -> bool:
    names = [d.func if isinstance(d, ast.Call) else d for d in node.decorator_list]
    return any(getattr(n, "id", getattr(n, "attr", "")) == "dataclass" for n in names)


def config_fields(files: list[Path]) -> tuple[int, int, int]:
    """(dataclasses named *Config, their fields, fields defaulting to None)."""
    classes = fields = nones = 0
    for path in files:
        for node in ast.walk(ast.parse(path.read_text())):
            if (
                isinstance(node, ast.ClassDef)
                and node.name.endswith("Config")
                and is_dataclass(node)
            ):
                classes += 1
                for item in node.body:
                    if isinstance(item, ast.AnnAssign) and "ClassVar" not in ast.unparse(
                        item.annotation
                    ):
                        fields += 1
                        nones += isinstance(item.value, ast.Constant) and item.value.value is None
    return classes, fields, nones


def long_docstrings(files: list[Path], lines: int = 15) -> int:
    count = 0
    for path in files:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
                doc = ast.get_docstring(node, clean=False)
                count += doc is not None and doc.count("\n") + 1 >= lines
    return count


def cli_flags() -> int:
    aed = Path(sys.executable).with_name("aed")
    total = 0
    for command in COMMANDS:
        text = subprocess.run(
            [str(aed), command, "--help"], capture_output=True, text=True, check=True
        ).stdout
        total += len(set(re.findall(r"^[│ ]\s*(--[a-z0-9-.]+)", text, re.MULTILINE)) - {"--help"})
    return total


def census() -> dict[str, int]:
    library = python_files(LIBRARY)
    everything = python_files((*LIBRARY, "scripts", "tests"))
    texts = {p: p.read_text() for p in everything}
    lib_texts = [texts[p] for p in library]
    classes, fields, nones = config_fields(library)
    script_classes, script_fields, _ = config_fields(python_files(("scripts",)))
    return {
        "library config dataclasses": classes,
        "library config fields": fields,
        "library fields defaulting to None": nones,
        "script config fields": script_fields,
        "places defining a profile (tables, branches, profile methods)": sum(
            len(PROFILE_TABLE.findall(t)) + len(PROFILE_BRANCH.findall(t)) for t in lib_texts
        ),
        "CLI flags (aed subcommands)": cli_flags(),
        "`# fmt: skip` (whole tree)": sum(t.count("# fmt: skip") for t in texts.values()),
        f"lines over {LINE_LIMIT} characters (whole tree)": sum(
            len(line) > LINE_LIMIT for t in texts.values() for line in t.splitlines()
        ),
        "docstrings of 15+ lines (library)": long_docstrings(library),
        "aed_models lines that are docstrings (%)": docstring_share(python_files(("aed_models",))),
    }


def docstring_share(files: list[Path]) -> int:
    doc = total = 0
    for path in files:
        text = path.read_text()
        total += text.count("\n")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef)):
                d = ast.get_docstring(node, clean=False)
                doc += d.count("\n") + 1 if d else 0
    return round(100 * doc / max(total, 1))


if __name__ == "__main__":
    counts = census()
    if "--json" in sys.argv:
        print(json.dumps(counts, indent=1))
    else:
        print("| count | value |\n|---|---|")
        for key, value in counts.items():
            print(f"| {key} | {value} |")
