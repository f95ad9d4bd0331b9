"""The order in which make test's workers take the tests (tests/scheduling.py)."""

from scheduling import lanes


def test_long_modules_lead_each_share_whole_and_the_rest_fills_them():
    groups = [[f"a{i}" for i in range(3)], [f"b{i}" for i in range(2)],
              [f"c{i}" for i in range(4)], [f"d{i}" for i in range(5)], ["e0"]]
    costs = [0, 100, 0, 200, 50]
    order = lanes(groups, costs, 2)
    assert sorted(order) == sorted(x for g in groups for x in g)  # nothing lost or repeated
    first, second = order[: len(order) // 2], order[len(order) // 2:]
    # the longest module starts the first share, the next the second, the third joins the
    # lighter share; each module stays in one piece
    assert first[:5] == [f"d{i}" for i in range(5)]
    assert second[:2] == ["b0", "b1"] and second[2] == "e0"
    # the light tests keep their order after the long ones
    light = [x for x in order if x[0] in "ac"]
    assert light == [f"a{i}" for i in range(3)] + [f"c{i}" for i in range(4)]


def test_one_worker_or_no_costs_keep_the_order():
    groups = [["a", "b"], ["c"], ["d", "e", "f"]]
    assert lanes(groups, [0, 0, 0], 2) == ["a", "b", "c", "d", "e", "f"]
    assert lanes(groups, [5, 0, 9], 1) == ["d", "e", "f", "a", "b", "c"]
