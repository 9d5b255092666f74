"""Every ```python block of the README and of docs/MAPPING.md runs as written (each in a fresh
namespace)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]
PAGES = ("README.md", "docs/MAPPING.md")
BLOCKS = {page: re.findall(r"```python\n(.*?)```", (ROOT / page).read_text(encoding="utf-8"),
                           flags=re.DOTALL) for page in PAGES}


@pytest.mark.parametrize("page", PAGES)
def test_the_page_has_its_python_example(page: str) -> None:
    assert BLOCKS[page]


@pytest.mark.parametrize(("page", "index"),
                         [(page, i) for page in PAGES for i in range(len(BLOCKS[page]))])
def test_python_block_runs(page: str, index: int) -> None:
    exec(compile(BLOCKS[page][index], f"{page} python block {index}", "exec"), {})  # noqa: S102
