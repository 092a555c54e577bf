"""The licence and the citation: LICENSE is the MIT licence, CITATION.cff is valid YAML in the Citation File Format
1.2.0 naming the software and, as a reference, the paper it reproduces; the README gives the same full reference."""

from __future__ import annotations

from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parent.parent
PAPER_TITLE = "Cooperative Lane Changing via Deep Reinforcement Learning"
PAPER_AUTHORS = [("Guan", "Wang"), ("Jianming", "Hu"), ("Zhiheng", "Li"), ("Li", "Li")]
"""as the paper's first lines give them (DESIGN.md's paper/cooperative-lane-changing-drl.md)"""
ARXIV = "1906.08662"


def _cff() -> dict:
    data = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert isinstance(data, dict)
    return data


def test_citation_cff_names_the_software() -> None:
    cff = _cff()
    assert cff["cff-version"] == "1.2.0" and cff["type"] == "software"
    assert all(cff.get(key) for key in ("message", "title", "authors"))  # the format's required keys
    assert cff["license"] == "MIT"
    assert cff["authors"] == [{"name": "the coopsumo authors"}]


def test_citation_cff_references_the_paper() -> None:
    (paper,) = [ref for ref in _cff()["references"] if ref["title"] == PAPER_TITLE]
    assert [(a["given-names"], a["family-names"]) for a in paper["authors"]] == PAPER_AUTHORS
    assert paper["year"] == 2019 and paper["type"] == "article"
    assert paper["url"] == f"https://arxiv.org/abs/{ARXIV}" and paper["doi"] == f"10.48550/arXiv.{ARXIV}"
    assert {"type": "other", "value": f"arXiv:{ARXIV}", "description": "the arXiv identifier"} in paper["identifiers"]


def test_the_readme_gives_the_full_reference_and_the_licence() -> None:
    first = " ".join((ROOT / "README.md").read_text().split("\n\n")[1].split())  # the first paragraph, unwrapped
    authors = ", ".join(f"{g} {f}" for g, f in PAPER_AUTHORS[:-1]) + " and {} {}".format(*PAPER_AUTHORS[-1])
    assert f'{authors}, "{PAPER_TITLE}", arXiv:{ARXIV}, 2019' in first
    assert "(LICENSE)" in first and "(CITATION.cff)" in first


def test_license_is_mit_for_the_coopsumo_authors() -> None:
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("MIT License\n\nCopyright (c) 2026 the coopsumo authors\n")
    assert "Permission is hereby granted, free of charge" in text and 'THE SOFTWARE IS PROVIDED "AS IS"' in text
