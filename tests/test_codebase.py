"""The code base's shape (issue 11's bars): no import circle, no private name across modules, docstrings short
and free of measured figures in tracker/ and segmentation/ (those live in docs/tuning.md)."""

from __future__ import annotations

from tests.support.codebase import cycles, docstring_findings, face_shadows, import_graph


def test_no_module_imports_another_in_a_circle():
    graph, _ = import_graph()
    assert cycles(graph) == []


def test_no_private_name_is_imported_across_modules():
    _, private = import_graph()
    assert private == []


def test_docstrings_are_short_and_hold_no_measured_figures():
    long, figures = docstring_findings()
    assert long == [], "docstrings over 30 lines"
    assert figures == [], "measured figures belong in docs/tuning.md or the README"


def test_no_package_face_exports_a_name_that_is_also_its_submodule():
    # ``from tracker.search import initialise`` gave the function or the module depending on import order
    assert face_shadows() == []


def test_the_checks_can_fail():
    # a circle and a private import in a hand-made graph are found
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []
