"""Text to glosses: spaCy tagging, lookup, fingerspelling, BSL reordering, coverage."""

import pytest

from signsplat.stitch import text as T


@pytest.fixture(scope="module")
def rules():
    return T.load_rules()


def test_reorders_to_bsl_time_location_subject_verb_negation(gloss_library, rules):
    plan = T.sentence_to_glosses("Yesterday I didn't go to school.", gloss_library, rules)
    assert plan.glosses == ["YESTERDAY", "SCHOOL", "ME", "GO", "NOT"]
    roles = {it.token: it.role for it in plan.items}
    assert roles["Yesterday"] == "time" and roles["school"] == "location"
    assert roles["n't"] == "negation"
    dropped = {it.token for it in plan.items if it.how == "dropped"}
    assert dropped == {"did", "to"}


def test_question_word_last_and_function_words_dropped(gloss_library, rules):
    plan = T.sentence_to_glosses("Where is the book?", gloss_library, rules)
    assert plan.glosses == ["BOOK", "WHERE"]
    c = plan.coverage()
    assert (c["words"], c["found"], c["dropped"], c["fingerspelled"]) == (4, 2, 2, 0)
    assert "2 found" in plan.coverage_line() and "2 dropped" in plan.coverage_line()


def test_lemma_synonym_phrase_and_fingerspelling(gloss_library, rules):
    plan = T.sentence_to_glosses("Hello, my name is Anna. Thank you!", gloss_library, rules)
    assert plan.glosses == ["HELLO", "MY", "NAME", "A", "N", "N", "A", "THANK-YOU"]
    how = {it.token: it.how for it in plan.items}
    assert how["Anna"] == "fingerspelled" and how["thank you"] == "phrase"
    plan = T.sentence_to_glosses("My mum loves books.", gloss_library, rules)
    how = {it.token: (it.how, it.glosses) for it in plan.items}
    assert how["loves"] == ("lemma", ("LIKE",))
    assert how["books"] == ("lemma", ("BOOK",))
    assert how["mum"][1] == ("MOTHER",)
    # synonym table: 'adore' is not a library word
    plan = T.sentence_to_glosses("They adore school.", gloss_library, rules)
    it = next(i for i in plan.items if i.token == "adore")
    assert it.how == "synonym" and it.glosses == ("LIKE",)


def test_empty_and_whitespace_sentences(gloss_library, rules):
    for s in ("", "   ", "\n"):
        plan = T.sentence_to_glosses(s, gloss_library, rules)
        assert plan.glosses == [] and plan.items == []
        assert plan.coverage()["words"] == 0
    plan = T.sentence_to_glosses("?!...", gloss_library, rules)
    assert plan.glosses == [] and plan.coverage()["words"] == 0


def test_unknown_words_only_are_all_fingerspelled(gloss_library, rules):
    plan = T.sentence_to_glosses("Xyzzy plugh quux", gloss_library, rules)
    assert "".join(plan.glosses) == "XYZZYPLUGHQUUX"
    assert all(gloss_library[g].kind == "letter" for g in plan.glosses)
    c = plan.coverage()
    assert c["fingerspelled"] == 3 and c["dropped"] == 0 and c["found"] == 0


def test_punctuation_and_casing_do_not_change_the_result(gloss_library, rules):
    base = T.sentence_to_glosses("Tomorrow I will eat at home.", gloss_library, rules).glosses
    assert base == ["TOMORROW", "HOME", "ME", "EAT"]
    for variant in ("TOMORROW I WILL EAT AT HOME!!!", "tomorrow, i will eat at home",
                    "Tomorrow... I will eat -- at home?"):
        assert T.sentence_to_glosses(variant, gloss_library, rules).glosses == base, variant


def test_fingerspell_accents_digits_and_symbols():
    assert T.fingerspell("Zoë") == ["Z", "O", "E"]
    assert T.fingerspell("B2") == ["B", "T", "W", "O"]
    assert T.fingerspell("ok!") == ["O", "K"]
    assert T.fingerspell("😀") == []


def test_unspellable_word_is_reported_not_silently_dropped(gloss_library, rules):
    plan = T.sentence_to_glosses("hello 😀", gloss_library, rules)
    assert plan.glosses == ["HELLO"]
    assert plan.coverage()["words"] >= 1
    # a library without letters cannot fingerspell: the word is listed as dropped with why
    signs_only = {k: v for k, v in gloss_library.items() if v.kind == "sign"}
    plan = T.sentence_to_glosses("hello Zed", signs_only, rules)
    it = next(i for i in plan.items if i.token == "Zed")
    assert it.how == "dropped" and "fingerspell" in it.rule


def test_rules_are_configurable(gloss_library, rules, tmp_path):
    import yaml

    data = yaml.safe_load(open(T.DEFAULT_RULES))
    data["order"] = ["interjection", "subject", "verb", "object", "time", "location",
                     "modifier", "negation", "question"]  # an English-like SVO order
    path = tmp_path / "svo.yaml"
    path.write_text(yaml.safe_dump(data))
    svo = T.load_rules(path)
    plan = T.sentence_to_glosses("Yesterday I didn't go to school.", gloss_library, svo)
    assert plan.glosses == ["ME", "GO", "YESTERDAY", "SCHOOL", "NOT"]
    del data["order"]
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(T.RulesError, match="order"):
        T.load_rules(path)
    with pytest.raises(T.RulesError, match="not found"):
        T.load_rules(tmp_path / "missing.yaml")


def test_missing_pipeline_says_how_to_install(gloss_library):
    with pytest.raises(T.PipelineMissingError, match="pip install"):
        T.load_pipeline("en_core_web_does_not_exist")


def test_plan_explains_itself(gloss_library, rules):
    plan = T.sentence_to_glosses("Why are you sad?", gloss_library, rules)
    assert plan.glosses == ["YOU", "SAD", "WHY"]
    text = plan.explain()
    assert "question word last" in text and "coverage:" in text
    import json
    data = json.loads(plan.to_json())
    assert data["glosses"] == plan.glosses and data["coverage"]["found"] == 3
