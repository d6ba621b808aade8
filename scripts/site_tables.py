"""Tables that fit the site's column at 1400 px: wide tables split, numbers kept whole, text allowed to wrap.

The committed tables (results/<profile>/tables/*.md, and the same tables a notebook prints) are written for the
paper and for diffs, one line per row; on the site a table of ten env columns or fifteen measures scrolled inside
its own box (issue 68). Only what the site shows changes here, never a committed file:

- a Markdown pipe table with env columns of both families (the rewards table) is shown as two tables, MuJoCo and
  Atari apart, each with the row's leading (non-env) columns;
- a number never breaks: in a cell of numbers ("0.014 [-0.083, 0.110]", "4961.5 ± 890.7 (n=3)") every
  space but the one before an interval or a count becomes a no-break space, so the estimate and its interval may
  sit on two lines and each stays whole;
- text may wrap at its natural joints: after '_' (snake_case names) and ';' (lists), before 'NoFrameskip'; never
  at the hyphen of an env's version ('Walker2d-v5');
- a DataFrame's cells: the same joints in its text, and a default 0..n-1 index (pandas' row numbers, noise on a
  results page) left out.
"""

from __future__ import annotations

import re

ZWSP = "\u200b"  # a place a line may break, invisible
NBSP = "\u00a0"
WORD_JOINER = "\u2060"  # no break here, invisible: 'Walker2d-v5' never splits at its hyphen
#: The hyphen of an env's version ('-v5'), where a browser would otherwise break a name in two.
VERSION_HYPHEN = re.compile(r"-(?=v\d)")
#: A pipe table's separator row: |---|:---|---:|
SEPARATOR = re.compile(r"^\|(\s*:?-+:?\s*\|)+\s*$")
#: The joints where text may wrap: after an underscore or a semicolon (dash_nan_tables adds: before 'NoFrameskip').
JOINT = re.compile(r"(?<=[_;])(?!\s)")
#: A space a number-with-interval cell may break at: before '[' or '(' (the interval, the count), nowhere else.
NUMBER_BREAK = re.compile(r" (?=[\[(])")
#: A cell of numbers only: "0.014 [-0.083, 0.110]", "4961.5 ± 890.7 (n=3)", "12.5%" (not "4 min 32 s", which is text).
NUMERIC = re.compile(r"^[-+\u2212]?\.?\d[\d.,eE+\-\u2212\u00b1%\s\[\]()n=]*$")


def env_family(name: str) -> str | None:
    """'MuJoCo' or 'Atari' for a column named after one of the paper's envs, else None."""
    from paper_lib.agents.envs import ATARI_ENVS, MUJOCO_ENVS

    name = name.replace(ZWSP, "").replace(WORD_JOINER, "").strip()
    return "MuJoCo" if name in MUJOCO_ENVS else "Atari" if name in ATARI_ENVS else None


def cells(line: str) -> list[str]:
    """The cells of one pipe-table row, their padding kept (a row is '| a | b |')."""
    return line.strip()[1:-1].split("|")


def row(parts: list[str]) -> str:
    return "|" + "|".join(parts) + "|"


def split_by_family(block: list[str]) -> list[list[str]]:
    """A pipe table (header, separator, rows) as one table per env family when its columns hold both families.

    The leading columns before the first env column (method, inference, actions) repeat in each table; a table
    whose env columns are of one family, or that has none, comes back as it is.
    """
    header = cells(block[0])
    families = [env_family(name) for name in header]
    if not {"MuJoCo", "Atari"} <= set(families):
        return [block]
    first = next(i for i, family in enumerate(families) if family)
    if any(family is None for family in families[first:]):
        return [block]  # a column after the envs that is no env (a mean): no clean split, shown whole
    parts = []
    for family in ("MuJoCo", "Atari"):
        keep = list(range(first)) + [i for i, f in enumerate(families) if f == family]
        parts.append([row([cells(line)[i] for i in keep]) for line in block])
    return parts


def wrap_cell(cell: str) -> str:
    """One body cell as the site shows it: a number (with its interval or count) whole, text's joints open."""
    inner = cell.strip()
    if not inner or "`" in inner or "](" in inner or "<" in inner:
        return cell  # empty, code, a link or HTML: left as written
    if NUMERIC.match(inner):
        inner = NUMBER_BREAK.sub("\0", inner).replace(" ", NBSP).replace("\0", " ")
    return cell.replace(cell.strip(), joints(inner))


def joints(text: str) -> str:
    """Text with its joints open (after '_' and ';') and an env name's version hyphen closed."""
    return VERSION_HYPHEN.sub("-" + WORD_JOINER, JOINT.sub(ZWSP, text))


def fit_block(block: list[str]) -> list[list[str]]:
    """A pipe table as the tables the site shows for it: split by env family, body cells wrapped (wrap_cell)."""
    shown = []
    for part in split_by_family(block):
        header = row([VERSION_HYPHEN.sub("-" + WORD_JOINER, c) for c in cells(part[0])])  # '_': dash_nan_tables
        body = [row([wrap_cell(c) for c in cells(line)]) for line in part[2:]]
        shown.append([header, part[1]] + body)
    return shown


def fit_tables(text: str) -> str:
    """Markdown with every pipe table outside code fences made to fit (fit_block); everything else as it is.

    A table split in two reads as two tables with a line naming each family between them (two tables need a
    paragraph between them, or Markdown reads them as one).
    """
    lines = text.splitlines()
    out: list[str] = []
    fenced = False
    i = 0
    while i < len(lines):
        line = lines[i]
        if line.lstrip().startswith(("```", "~~~")):
            fenced = not fenced
        if fenced or not line.startswith("|") or i + 1 >= len(lines) or not SEPARATOR.match(lines[i + 1]):
            out.append(line)
            i += 1
            continue
        end = next((j for j in range(i, len(lines)) if not lines[j].startswith("|")), len(lines))
        parts = fit_block(lines[i:end])
        for n, part in enumerate(parts):
            if len(parts) > 1:
                family = env_family(next(c for c in cells(part[0]) if env_family(c)))
                out += ([] if n == 0 else [""]) + [f"*{family}:*", ""]
            out += part
        i = end
    return "\n".join(out) + ("\n" if text.endswith("\n") else "")


#: pandas' default index in a DataFrame's HTML: a row header cell holding the row's number.
TEXT_CELL = re.compile(r"<td>([^<]*[A-Za-z_;][^<]*)</td>")
ROW = re.compile(r"<tr[^>]*>(.*?)</tr>", re.DOTALL)
CELL = re.compile(r"<(t[hd])([^>]*)>(.*?)</t[hd]>", re.DOTALL)
#: What a table may take at 1400 px: the column of a notebook page (paper_lib.reporting.display), less a margin for
#: the estimate's error.
MARGIN_PX = 42
#: The width of one character of a table cell (0.8rem of the theme's sans-serif) and of a cell's padding, in px:
#: estimates that err wide (measured: 6.5-7.3 px a character).
CHAR_PX, PAD_PX = 7.5, 10


def fit_dataframe(html: str) -> str:
    """A DataFrame's HTML as the site shows it: the default index left out, text's joints open, split if too wide.

    The index is dropped only where it is pandas' default (every row header the row's number, in order), so a
    meaningful index (an env, a method) stays. A table still wider than the column (estimated from its longest
    unbreakable words) is shown as two tables, per group of measures: its leading text columns (env, method, ...)
    in both, its other columns halved between them.
    """
    numbers = re.findall(r"<tr>\s*<th>(\d+)</th>", html)
    if numbers and numbers == [str(n) for n in range(len(numbers))]:
        html = re.sub(r"(<tr[^>]*>)\s*<th></th>", r"\1", html, count=1)  # the index's empty header
        html = re.sub(r"(<tr>)\s*<th>\d+</th>", r"\1", html)
    html = TEXT_CELL.sub(lambda m: f"<td>{joints(m.group(1)).replace('NoFrameskip', ZWSP + 'NoFrameskip')}</td>",
                         html)
    return split_dataframe(html)


def estimated_width(columns: list[list[str]]) -> float:
    """The least width in px a table of these columns (each: its header, then its cells) takes: longest words."""
    def word(text: str) -> int:
        return max((len(w) for w in re.split(r"[\s\u200b]+", re.sub(r"<[^>]+>", "", text)) if w), default=0)

    return sum(max(map(word, column)) * CHAR_PX + PAD_PX for column in columns)


def split_dataframe(html: str) -> str:
    """A DataFrame's HTML table as one table, or as two (per group of measures) where it is wider than the column."""
    start, end = html.find("<table"), html.find("</table>")
    rows = [CELL.findall(r) for r in ROW.findall(html[start:end])]
    if start < 0 or html.count("<table") != 1 or html.count("<tr") != len(rows) or len(rows) < 2:
        return html  # not one plain table: left as it is
    if html[start:end].count("</thead>") != 1 or html[start:html.find("</thead>")].count("<tr") != 1:
        return html  # a header of several rows (MultiIndex columns): left as it is
    if len({len(r) for r in rows}) != 1:
        return html
    columns = [list(column) for column in zip(*[[text for _, _, text in r] for r in rows])]
    from paper_lib.reporting.display import COLUMN_PX

    if estimated_width(columns) <= COLUMN_PX - MARGIN_PX:
        return html
    keys = 0  # the leading columns that say what a row is: the index (row headers) and text (env, method, score)
    while keys < len(columns) - 2 and all(tag == "th" or not NUMERIC.match(text.strip())
                                          for tag, _, text in (r[keys] for r in rows[1:])):
        keys += 1
    rest = list(range(keys, len(columns)))
    halves = [rest[: (len(rest) + 1) // 2], rest[(len(rest) + 1) // 2:]]
    tables = []
    for half in halves:
        keep = list(range(keys)) + half
        head = "".join(f"<{t}{a}>{x}</{t}>" for t, a, x in (rows[0][i] for i in keep))
        body = "".join("<tr>" + "".join(f"<{t}{a}>{x}</{t}>" for t, a, x in (r[i] for i in keep)) + "</tr>\n"
                       for r in rows[1:])
        tables.append(f'<table border="1" class="dataframe">\n<thead><tr>{head}</tr></thead>\n<tbody>\n{body}</tbody>\n'
                      "</table>")
    return html[:start] + "\n".join(tables) + html[end + len("</table>"):]
