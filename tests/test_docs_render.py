"""The manual renders as written: what `mkdocs build --strict` does not catch. The site is built into a
temporary directory and each page's HTML is checked against its Markdown source:

- every fenced code block of the source is a `<pre><code>` block of the page, and no fence is left as text
  (Python-Markdown's fences must start at the margin: a fence indented inside a list item is not one, and the
  fence after it then swallows the prose up to the next one into a code block);
- every heading of the source is a heading of the page (a swallowed section loses its headings);
- a list starts after a blank line: a list item written directly under a paragraph line runs into that
  paragraph (`- a - b` as one line of text).

Each check is shown able to fail on a small page written the broken way (the negative controls)."""

import html
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FENCE = re.compile(r"^(?P<indent> *)(?P<fence>`{3,}|~{3,})")
LIST_ITEM = re.compile(r"^(?:[-*+]|\d+[.)]) \S")
HEADING = re.compile(r"^(#{1,6}) +(.+?) *#*$")
# inline code that was meant as a block: a fence's language word (or nothing) and then a line break
INLINE_BLOCK = re.compile(r"^(?:sh|bash|console|shell|yaml|yml|json|python|py|text|ini|toml|[\w.+-]*walkthrough)?[ \t]*\n")


# the opening fence Python-Markdown's fenced_code reads: a language word, or {attributes} (`{.sh .walkthrough}`),
# nothing else (`sh walkthrough` is no fence to it)
PM_FENCE_OPEN = re.compile(r"^(?:~{3,}|`{3,})[ ]*(?:\{[^\n]*\}|\.?[\w#.+-]*)[ ]*$")


def source_structure(text: str) -> dict:
    """What a page's Markdown means to its author, read as CommonMark would: its fenced blocks (a fence at any
    indent, e.g. inside a list item), its headings outside code, fences Python-Markdown will not read (indented,
    or with an info string it does not take), and list items written directly under a paragraph line (line
    numbers from 1)."""
    fenced, unread, headings, glued = 0, [], [], []
    fence = None
    block = None  # the kind of block the current run of non-blank lines started as: "para", "list", "other"
    for n, line in enumerate(text.splitlines(), 1):
        m = FENCE.match(line)
        if fence is not None:
            if m and m["fence"][0] == fence[0] and len(m["fence"]) >= len(fence) \
                    and not line.strip()[len(m["fence"]):].strip():
                fence, block = None, None
            continue
        if m:
            fence, block = m["fence"], None
            fenced += 1
            if m["indent"] or not PM_FENCE_OPEN.match(line):
                unread.append(n)
            continue
        if not line.strip():
            block = None
            continue
        if HEADING.match(line):
            headings.append(HEADING.match(line)[2])
            block = None
            continue
        if block is None:
            block = "list" if LIST_ITEM.match(line) else "other" if line.startswith(("|", "<", "    ", ">")) \
                else "para"
        elif block == "para" and LIST_ITEM.match(line):
            glued.append(n)  # (the list goes on from here: its further items are not counted again)
            block = "list"
    return {"fenced": fenced, "unread_fences": unread, "headings": headings, "glued_lists": glued}


def _text(fragment: str) -> str:
    return html.unescape(re.sub(r"<[^>]+>", "", fragment)).strip()


def html_structure(page: str) -> dict:
    """What the built page shows: its code blocks, its headings' text, fences left in the text, and paragraphs
    holding a list written as text."""
    body = page[page.find('<div role="main"'):] if '<div role="main"' in page else page
    blocks = re.findall(r"<pre[^>]*>\s*<code[^>]*>(.*?)</code>\s*</pre>", body, re.S)
    outside = re.sub(r"<pre[^>]*>.*?</pre>", "", body, flags=re.S)
    headings = [_text(re.sub(r'<a class="headerlink".*?</a>', "", h)) for h in
                re.findall(r"<h[1-6][^>]*>(.*?)</h[1-6]>", outside, re.S)]
    paragraphs = [_text(p) for p in re.findall(r"<p>(.*?)</p>", outside, re.S)]
    inline_blocks = [_text(c)[:40] for c in re.findall(r"<code[^>]*>(.*?)</code>", outside, re.S) if INLINE_BLOCK.match(_text(c))]
    return {"code_blocks": len(blocks), "headings": headings, "inline_blocks": inline_blocks,
            "fence_as_text": "```" in _text(outside) or "~~~" in _text(outside),
            "list_in_paragraph": [p[:80] for p in paragraphs if re.search(r"\n(?:[-*+]|\d+[.)]) \S", p)]}


def heading_text(markdown_heading: str) -> str:
    """A source heading as the page shows it: inline markup gone, `{#id}` attributes dropped."""
    t = re.sub(r"\s*\{[^}]*\}\s*$", "", markdown_heading)
    t = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", t)
    return html.unescape(re.sub(r"[`*_]", "", t)).strip()


def problems(source: str, page: str) -> list[str]:
    src, out = source_structure(source), html_structure(page)
    found = []
    if src["unread_fences"]:
        found.append(f"fences the site does not read (indented, e.g. in a list item, or an info string other than "
                     f"a language and {{attributes}}): lines {src['unread_fences']}")
    if out["code_blocks"] < src["fenced"]:  # (more: indented code blocks)
        found.append(f"{src['fenced']} fenced code blocks written, {out['code_blocks']} rendered")
    if out["fence_as_text"]:
        found.append("a fence shows as text")
    if out["inline_blocks"]:
        found.append(f"a code block shown inline, in a paragraph: {out['inline_blocks']}")
    shown = {re.sub(r"[`*_]", "", h) for h in out["headings"]}
    lost = [h for h in map(heading_text, src["headings"]) if h not in shown]
    if lost:
        found.append(f"headings not rendered as headings: {lost}")
    if src["glued_lists"]:
        found.append(f"list items directly under a paragraph line (no blank line before the list): lines "
                     f"{src['glued_lists']}")
    if out["list_in_paragraph"]:
        found.append(f"a list rendered as a paragraph: {out['list_in_paragraph']}")
    return found


def build(root: Path, site: Path) -> None:
    r = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--site-dir", str(site), "--config-file",
                        str(root / "mkdocs.yml")], cwd=root, capture_output=True, text=True, timeout=600, check=False)
    assert r.returncode == 0, r.stdout + r.stderr


def built_page(site: Path, md: Path, docs: Path) -> Path:
    rel = md.relative_to(docs).with_suffix("")
    return site / "index.html" if rel.name == "index" and rel.parent == Path(".") else site / rel / "index.html"


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    out = tmp_path_factory.mktemp("site")
    build(ROOT, out)
    return out


PAGES = sorted((ROOT / "docs").glob("*.md"))


@pytest.mark.parametrize("md", PAGES, ids=lambda p: p.name)
def test_each_page_renders_as_written(site, md):
    page = built_page(site, md, ROOT / "docs")
    assert page.is_file(), page
    assert problems(md.read_text(), page.read_text()) == []


# ------------------------------------------------------------------ negative controls: pages written the broken way
BROKEN = {
    "fence in a list item": "# P\n\n1. Build it:\n\n   ```sh\n   make\n   ```\n\n## 4. Next\n\nText.\n\n```sh\nrun\n```\n\n"
                            "## 5. Last\n\nMore.\n",
    "list under a paragraph": "# P\n\nThe parts are:\n- one\n- two\n",
    "fence with a walk-through tag": "# P\n\n```sh walkthrough\nrun\n```\n\n## 4. Next\n\nText.\n\n"
                                     "```sh walkthrough\nmore\n```\n\n## 5. Last\n",
}
GOOD = "# P\n\nBuild it:\n\n```{.sh .walkthrough}\nmake\n```\n\n## 4. Next\n\nThe parts are:\n\n- one\n- two\n\n```sh\nrun\n```\n"


@pytest.fixture(scope="module")
def toy_site(tmp_path_factory):
    root = tmp_path_factory.mktemp("toy")
    (root / "docs").mkdir()
    for i, text in enumerate([GOOD, *BROKEN.values()]):
        (root / "docs" / f"p{i}.md").write_text(text)
    (root / "mkdocs.yml").write_text("site_name: toy\ndocs_dir: docs\ntheme:\n  name: mkdocs\nmarkdown_extensions:\n"
                                     "  - toc:\n      permalink: true\n  - attr_list\n  - tables\n  - fenced_code\n")
    build(root, root / "site")
    return root


def toy(root: Path, i: int) -> tuple[str, str]:
    md = root / "docs" / f"p{i}.md"
    return md.read_text(), built_page(root / "site", md, root / "docs").read_text()


def test_a_page_written_well_passes(toy_site):
    assert problems(*toy(toy_site, 0)) == []


@pytest.mark.parametrize("i,kind", list(enumerate(BROKEN, 1)), ids=list(BROKEN))
def test_a_page_written_the_broken_way_is_caught(toy_site, i, kind):
    found = problems(*toy(toy_site, i))
    assert found, kind
    if kind == "fence in a list item":  # rendered as inline code in a paragraph
        assert any("indented" in f for f in found) and any("shown inline" in f for f in found), found
    if kind == "list under a paragraph":
        assert any("no blank line before the list" in f for f in found) and \
            any("list rendered as a paragraph" in f for f in found), found
    if kind == "fence with a walk-through tag":  # the fence is text; the next one swallows the section between
        assert any("headings not rendered" in f and "4. Next" in f for f in found), found
        assert any("2 fenced code blocks written, 1 rendered" in f for f in found), found
        assert any("info string" in f for f in found), found
