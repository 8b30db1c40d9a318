"""The fenced code blocks of README.md, for the README tests and `.ci/run` (stdlib only).

    python3 tests/readme_blocks.py bash "Two commands"   # NUL-separated, for .ci/run
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

README = Path(__file__).resolve().parent.parent / "README.md"
_FENCE = re.compile(r"^```(\w*)[ \t]*\n(.*?)^```[ \t]*$", re.MULTILINE | re.DOTALL)


def blocks(language: str, section: str | None = None, text: str | None = None) -> list[str]:
    """The bodies of the ```language blocks, in order; only under the heading `section`
    (a ``## section`` line, up to the next ``## `` heading) when given."""
    text = README.read_text(encoding="utf-8") if text is None else text
    if section is not None:
        parts = re.split(r"^## ", text, flags=re.MULTILINE)
        text = next((p for p in parts if p.split("\n", 1)[0].strip() == section), "")
    return [body for lang, body in _FENCE.findall(text) if lang == language]


if __name__ == "__main__":
    language, section = sys.argv[1], (sys.argv[2] if len(sys.argv) > 2 else None)
    sys.stdout.write("".join(b.strip() + "\0" for b in blocks(language, section)))
