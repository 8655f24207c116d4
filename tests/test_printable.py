"""What a peer sends, shown: no character that steers a terminal gets through, and what
is shown reads back to what was sent (errors.printable)."""

from __future__ import annotations

import re

from hypothesis import given
from hypothesis import strategies as st

from omnican.errors import printable

_ESCAPE = re.compile(r"\\(\\|x[0-9a-f]{2}|u[0-9a-f]{4}|U[0-9a-f]{8})")


def unescaped(shown: str) -> str:
    """The inverse of printable (without a limit)."""
    return _ESCAPE.sub(lambda m: "\\" if m[1] == "\\" else chr(int(m[1][1:], 16)), shown)


@given(st.text())
def test_nothing_unprintable_gets_through_and_it_reads_back(text: str) -> None:
    shown = printable(text)
    assert shown.isprintable()
    assert unescaped(shown) == text


@given(st.text(st.characters(blacklist_categories=("Cc", "Cf", "Cs", "Co", "Cn", "Zl",
                                                     "Zp", "Zs"), blacklist_characters="\\")
               | st.just(" ")))
def test_printable_text_stays_as_it_is(text: str) -> None:
    assert printable(text) == text


@given(st.text(), st.integers(0, 50))
def test_a_limit_cuts_and_says_how_long_it_was(text: str, limit: int) -> None:
    shown = printable(text, limit)
    assert shown.isprintable()
    if len(text) <= limit:
        assert shown == printable(text)
    else:
        assert shown == f"{printable(text[:limit])}... ({len(text)} characters)"


def test_the_escapes_a_terminal_would_obey_are_written_out() -> None:
    assert printable("/evil\x1b[2J\x1b]0;PWNED\x07/x") == "/evil\\x1b[2J\\x1b]0;PWNED\\x07/x"
    assert printable("a\u202eb\u2028c\x9bd\x7f") == "a\\u202eb\\u2028c\\x9bd\\x7f"
    assert printable("back\\x1b slash") == "back\\\\x1b slash"  # not taken for an escape
    assert printable("Grüße, 東京 \U0001f916") == "Grüße, 東京 \U0001f916"
