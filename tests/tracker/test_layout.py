"""The shape of tracker/ and segmentation/ (issue 11 bars): no import circle, no private name imported
across modules, no docstring over 30 lines, no measured figure in a docstring (``tests.support.codebase``)."""

from __future__ import annotations

from tests.support.codebase import cycles, docstring_findings, import_graph

OURS = ("tracker", "segmentation")


def _ours(text: str) -> bool:
    return text.split("/")[0] in OURS or text.split(".")[0] in OURS


def test_no_import_circle_or_private_import():
    graph, private = import_graph()
    assert [c for c in cycles(graph) if any(_ours(m) for m in c)] == []
    assert [p for p in private if _ours(p)] == []


def test_search_is_a_bottom_up_chain():
    graph, _ = import_graph()
    chain = ["hull", "scoring", "candidates", "refine", "mirror", "initialise", "recovery"]
    for i, name in enumerate(chain):
        below = {f"tracker.search.{m}" for m in chain[i + 1:]}
        assert not graph[f"tracker.search.{name}"] & below, name


def test_docstrings_short_and_free_of_measured_figures():
    long, figures = docstring_findings()
    assert [x for x in long if _ours(x)] == []
    assert [x for x in figures if _ours(x)] == []
