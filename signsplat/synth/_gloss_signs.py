"""The synthetic gloss library as data: each sign is handshape + location + orientation +
movement (+ non-manual features), each letter of the two-handed (BSL-style) fingerspelling
alphabet a handshape placed on a point of the non-dominant hand.

These are synthetic approximations built from the usual phonological parameters of sign
languages (Stokoe's handshape / location / movement, plus orientation and non-manual
features); they are not reference BSL citation forms.

Conventions: the dominant hand is the right hand. Directions are names relative to a side
('in' = towards the body midline, 'out' = away from it; 'up', 'down', 'forward', 'back') or
sums of names ('up+forward'). Offsets are (out, up, forward) in metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class Move:
    """A movement of the hand over the sign, parameterised on eased time t in [0, 1].

    kind: 'hold'; 'tap' (approach ``dir`` to contact ``n`` times); 'away' (from the location
    along ``dir`` by ``amp``); 'toward' (from ``amp`` along ``dir`` to the location); 'repeat'
    (back and forth along ``dir`` ``n`` times); 'shake' (side to side along ``dir``, ``n``
    cycles); 'circle' (``n`` turns of radius ``amp`` in the plane normal to ``dir``);
    'arc' (like 'away' with a bump of ``height`` upwards).
    """

    kind: str = "hold"
    dir: str = "forward"
    amp: float = 0.0
    n: int = 1
    height: float = 0.0


@dataclass(frozen=True)
class Hand:
    """One hand of a sign. ``loc`` is a body location name of the skeleton or
    'nondom:<point>' (a point of the other hand, e.g. 'nondom:palm', 'nondom:index_tip')."""

    shape: str
    loc: str
    palm: str
    fingers: str
    contact: str = "palm"           # point of this hand placed at ``loc``
    offset: tuple = (0.0, 0.0, 0.0)  # (out, up, forward) metres
    move: Move = field(default_factory=Move)
    end_shape: str | None = None
    twist: float = 0.0              # degrees about the finger axis over the sign


@dataclass(frozen=True)
class Sign:
    """A gloss. ``nondom``: None (rests), 'mirror' (symmetric), 'alternate' (mirror, half a
    cycle out of phase) or its own :class:`Hand`. ``nmf``: non-manual features, names of
    :data:`NMF_NAMES`."""

    gloss: str
    words: tuple
    dom: Hand
    nondom: Hand | str | None = None
    nmf: tuple = ()
    duration: float = 1.0
    kind: str = "sign"


NMF_NAMES = ("nod", "shake", "question", "yn_question", "smile", "frown", "brow_raise",
             "puff", "mouth")

REST = Hand("relaxed", "rest", palm="in", fingers="down+forward")

_Q = ("question",)

SIGNS: tuple[Sign, ...] = (
    Sign("HELLO", ("hello", "hi", "hey"),
         Hand("B", "temple", "forward", "up", contact="index_tip", offset=(0.02, 0.01, 0.02),
              move=Move("arc", "out+forward", 0.16, height=0.03)), nmf=("smile",)),
    Sign("THANK-YOU", ("thank", "thanks"),
         Hand("B", "chin", "back", "up+in", contact="middle_tip", offset=(0.0, 0.0, 0.03),
              move=Move("away", "forward+down", 0.2)), nmf=("smile", "nod")),
    Sign("PLEASE", ("please",),
         Hand("B", "mouth", "in", "up", contact="index_tip", offset=(0.0, 0.0, 0.01),
              move=Move("away", "forward+down", 0.12)), nmf=("smile",)),
    Sign("YES", ("yes", "yeah", "ok", "okay"),
         Hand("S", "neutral_side", "down", "forward", move=Move("repeat", "down", 0.05, 2)),
         nmf=("nod",)),
    Sign("NO", ("no", "none", "nothing"),
         Hand("B", "neutral_side", "down", "forward", move=Move("shake", "in", 0.05, 2)),
         nmf=("shake", "frown")),
    Sign("NOT", ("not", "never"),
         Hand("B", "neutral", "down", "forward+in", offset=(-0.02, 0.0, 0.0),
              move=Move("away", "out", 0.2)), nmf=("shake",)),
    Sign("BOOK", ("book", "read"),
         Hand("B", "neutral", "in", "forward", offset=(0.03, 0.0, 0.0), twist=-80.0),
         nondom="mirror"),
    Sign("HOUSE", ("house", "building"),
         Hand("B", "high", "in+down", "up+forward", contact="middle_tip", offset=(0.03, -0.05, 0.0),
              move=Move("arc", "down+out", 0.17, height=0.0)), nondom="mirror"),
    Sign("NAME", ("name", "call"),
         Hand("H", "forehead", "in", "up", contact="middle_tip", offset=(0.065, 0.0, 0.02),
              move=Move("away", "forward+out", 0.12))),
    Sign("WHAT", ("what",),
         Hand("1", "neutral_side", "down", "in+forward", contact="index1",
              move=Move("shake", "in", 0.035, 3)), nmf=_Q),
    Sign("WHERE", ("where",),
         Hand("5", "neutral_side", "up", "forward", move=Move("shake", "out", 0.05, 2)),
         nondom="alternate", nmf=_Q),
    Sign("WHO", ("who", "whom", "whose"),
         Hand("1", "chin", "back", "up", contact="index_tip", offset=(0.0, 0.0, 0.065),
              move=Move("circle", "back", 0.02, 2)), nmf=_Q),
    Sign("WHY", ("why", "reason"),
         Hand("B", "shoulder_front", "in", "up+forward", contact="index_tip",
              offset=(0.015, 0.0, 0.06), move=Move("tap", "forward", 0.05, 2)), nmf=_Q),
    Sign("HOW", ("how",),
         Hand("A", "neutral", "back", "in", contact="index2", offset=(0.02, 0.0, 0.0),
              twist=70.0), nondom="mirror", nmf=_Q),
    Sign("FRIEND", ("friend", "mate", "pal"),
         Hand("S", "nondom:index1", "down", "in+forward", contact="palm",
              offset=(0.0, 0.035, 0.0), move=Move("repeat", "up", 0.04, 2)),
         nondom=Hand("S", "neutral", "in", "forward", contact="palm", offset=(0.03, 0.0, 0.0)),
         nmf=("smile",)),
    Sign("FAMILY", ("family",),
         Hand("F", "nondom:back", "down", "forward", contact="middle_tip",
              offset=(0.0, 0.08, 0.0), move=Move("circle", "up", 0.06, 1)),
         nondom=Hand("S", "neutral", "down", "forward+in", offset=(0.04, 0.0, 0.0))),
    Sign("MOTHER", ("mother", "mum", "mom", "mam"),
         Hand("M", "nondom:palm", "in", "in+down", contact="middle_tip",
              move=Move("tap", "out", 0.04, 2)),
         nondom=Hand("B", "neutral", "out", "forward+up", offset=(0.05, 0.0, 0.0))),
    Sign("FATHER", ("father", "dad", "daddy"),
         Hand("H", "nondom:index2", "down", "in+forward", contact="middle2",
              move=Move("tap", "up", 0.04, 2)),
         nondom=Hand("H", "neutral", "in", "forward+in", offset=(0.05, 0.0, 0.0))),
    Sign("EAT", ("eat", "food", "meal"),
         Hand("flat_O", "mouth", "back", "up+back", contact="middle_tip",
              offset=(0.0, 0.0, 0.01), move=Move("tap", "forward", 0.05, 2)),
         nmf=("mouth",)),
    Sign("DRINK", ("drink", "water"),
         Hand("C", "chin", "in", "back+up", contact="thumb_tip", offset=(0.0, 0.0, 0.03),
              move=Move("away", "up", 0.04), twist=-40.0), nmf=("mouth",)),
    Sign("GO", ("go", "leave", "walk"),
         Hand("1", "neutral", "down", "forward+up", contact="index1",
              move=Move("arc", "forward+out", 0.22, height=0.04))),
    Sign("COME", ("come", "arrive"),
         Hand("1", "neutral", "up", "forward+up", contact="index1", offset=(0.0, 0.02, 0.1),
              move=Move("away", "back", 0.18), end_shape="X")),
    Sign("WANT", ("want", "need", "wish"),
         Hand("B", "chest", "back", "in", contact="palm", offset=(0.0, 0.05, 0.02),
              move=Move("away", "down", 0.12))),
    Sign("LIKE", ("like", "love", "enjoy"),
         Hand("B", "chest", "back", "in+up", contact="palm", offset=(0.0, 0.0, 0.01),
              move=Move("tap", "forward", 0.04, 2)), nmf=("smile",)),
    Sign("HAPPY", ("happy", "glad", "pleased"),
         Hand("B", "nondom:palm", "down", "forward+in", contact="palm",
              move=Move("circle", "up", 0.035, 2)),
         nondom=Hand("B", "neutral", "up", "forward+in", offset=(0.05, -0.02, 0.0)),
         nmf=("smile",)),
    Sign("SAD", ("sad", "unhappy", "sorry"),
         Hand("B", "nose", "in", "up", contact="index_tip", offset=(0.0, 0.03, 0.03),
              move=Move("away", "down", 0.15)), nmf=("frown",), duration=1.2),
    Sign("GOOD", ("good", "well", "fine", "great", "nice"),
         Hand("thumb_up", "neutral_side", "in", "forward", move=Move("away", "forward", 0.08)),
         nmf=("smile", "nod")),
    Sign("BAD", ("bad", "wrong", "terrible"),
         Hand("I", "neutral_side", "in", "forward", move=Move("away", "forward+down", 0.08)),
         nmf=("frown",)),
    Sign("TOMORROW", ("tomorrow",),
         Hand("1", "cheek", "back", "up", contact="index_tip", offset=(0.0, 0.0, 0.04),
              move=Move("arc", "forward", 0.14, height=0.02))),
    Sign("YESTERDAY", ("yesterday",),
         Hand("1", "cheek", "down", "back+up", contact="index_tip", offset=(0.02, 0.0, 0.02),
              move=Move("away", "back+out", 0.1))),
    Sign("TODAY", ("today", "now"),
         Hand("B", "neutral", "up", "forward", offset=(0.12, 0.0, 0.0),
              move=Move("away", "down", 0.07)), nondom="mirror"),
    Sign("SCHOOL", ("school", "teach", "class", "lesson"),
         Hand("1", "temple", "forward", "up+in", contact="index_tip", offset=(0.06, 0.0, 0.03),
              move=Move("repeat", "forward+down", 0.12, 2)), nondom="mirror"),
    Sign("WORK", ("work", "job"),
         Hand("B", "nondom:back", "in", "forward", contact="edge", offset=(0.0, 0.02, 0.0),
              move=Move("tap", "up", 0.05, 2)),
         nondom=Hand("B", "neutral", "down", "forward+in", offset=(0.03, 0.0, 0.0))),
    Sign("HOME", ("home",),
         Hand("flat_O", "cheek", "back", "up", contact="middle_tip", offset=(0.0, 0.0, 0.01),
              move=Move("tap", "out", 0.04, 2))),
    Sign("MY", ("my", "mine", "our"),
         Hand("B", "chest", "back", "up+in", contact="palm", move=Move("tap", "forward", 0.04, 1)),
         duration=0.7),
    Sign("YOU", ("you", "your", "yours"),
         Hand("1", "neutral", "down", "forward", contact="index1",
              move=Move("away", "forward", 0.06)), duration=0.7),
    Sign("ME", ("i", "me", "myself"),
         Hand("1", "chest", "forward", "in", contact="index_tip", offset=(0.02, 0.0, 0.01),
              move=Move("tap", "forward", 0.04, 1)), duration=0.7),
    Sign("HELP", ("help", "support", "assist"),
         Hand("thumb_up", "nondom:palm", "in", "forward", contact="edge",
              move=Move("hold")),
         nondom=Hand("B", "neutral", "up", "forward+in", offset=(0.03, -0.06, 0.0),
                     move=Move("away", "forward+up", 0.12))),
    Sign("LEARN", ("learn", "study"),
         Hand("5", "forehead", "back", "up", contact="middle_tip", offset=(0.0, 0.0, 0.02),
              move=Move("toward", "forward+down", 0.25), end_shape="flat_O")),
    Sign("SIGN", ("sign", "signing", "language"),
         Hand("1", "neutral", "in+down", "in+forward", offset=(0.07, 0.0, 0.0),
              move=Move("circle", "in", 0.06, 2)), nondom="alternate"),
    Sign("FINISH", ("finish", "done", "finished", "already", "complete"),
         Hand("5", "neutral", "in", "forward", offset=(0.1, 0.0, 0.0), twist=90.0,
              move=Move("away", "out", 0.06)), nondom="mirror"),
    Sign("THINK", ("think", "believe", "idea"),
         Hand("1", "temple", "down", "up+in", contact="index_tip",
              move=Move("tap", "out", 0.04, 2))),
    Sign("KNOW", ("know", "knowledge"),
         Hand("thumb_up", "temple", "in", "up", contact="thumb_tip", offset=(0.0, 0.0, 0.01),
              move=Move("tap", "out", 0.04, 1))),
    Sign("DEAF", ("deaf",),
         Hand("H", "ear", "in", "up+forward", contact="middle_tip", offset=(0.03, 0.0, 0.02),
              move=Move("tap", "out", 0.04, 2))),
    Sign("WHEN", ("when", "time"),
         Hand("1", "nondom:back", "down", "in", contact="index_tip",
              move=Move("tap", "up", 0.05, 2)),
         nondom=Hand("S", "neutral", "down", "forward+in", offset=(0.03, 0.0, 0.0)),
         nmf=_Q),
    Sign("MORNING", ("morning",),
         Hand("B", "chest", "up", "in", contact="palm", offset=(0.0, -0.08, 0.05),
              move=Move("away", "up+forward", 0.15))),
    Sign("DAY", ("day",),
         Hand("1", "neutral", "forward", "up", offset=(0.15, 0.2, 0.0),
              move=Move("arc", "in", 0.25, height=0.06))),
    Sign("WELCOME", ("welcome",),
         Hand("B", "neutral", "up", "forward+out", offset=(0.15, 0.0, 0.1),
              move=Move("away", "back+in", 0.15)), nondom="mirror", nmf=("smile",)),
)


# --- fingerspelling ---------------------------------------------------------------------------
# The non-dominant (left) hand is the spelling base: flat, palm towards the signer and the
# right hand, fingers up. Vowels: the right index touches a fingertip (A thumb .. U little
# finger). Consonants: a right-hand shape placed on a point of the base hand, loosely after
# the BSL two-handed manual alphabet.

SPELL_BASE = Hand("B", "neutral", "in+back", "up+in", offset=(0.05, 0.02, -0.03))
_TAP = Move("tap", "out+up", 0.02, 1)

# letter: (dom shape, dom contact, base point, dom palm, dom fingers, base handshape or None)
LETTERS: dict[str, tuple] = {
    "A": ("1", "index_tip", "thumb_tip", "down", "in", None),
    "E": ("1", "index_tip", "index_tip", "down", "in", None),
    "I": ("1", "index_tip", "middle_tip", "down", "in", None),
    "O": ("1", "index_tip", "ring_tip", "down", "in", None),
    "U": ("1", "index_tip", "pinky_tip", "down", "in", None),
    "B": ("O", "index2", "index2", "in", "forward", "O"),
    "C": ("C", "thumb_tip", "index1", "in", "forward", None),
    "D": ("L", "index_tip", "index2", "in", "forward", None),
    "F": ("H", "middle_tip", "index2", "down", "in", "H"),
    "G": ("S", "palm", "back", "down", "in", "S"),
    "H": ("B", "palm", "palm", "in", "forward", None),
    "J": ("1", "index_tip", "palm", "in", "forward", None),
    "K": ("X", "index2", "index1", "down", "in", None),
    "L": ("1", "index_tip", "palm", "down", "in", None),
    "M": ("W", "middle_tip", "palm", "in", "forward", None),
    "N": ("V", "middle_tip", "palm", "in", "forward", None),
    "P": ("F", "index_tip", "index1", "down", "in", None),
    "Q": ("C", "index_tip", "index_tip", "in+forward", "up+forward", "1"),
    "R": ("X", "index2", "palm", "in", "forward", None),
    "S": ("I", "pinky_tip", "pinky_tip", "down", "in", "I"),
    "T": ("1", "index_tip", "heel", "in+down", "in+forward", None),
    "V": ("V", "index_tip", "palm", "in+down", "forward", None),
    "W": ("5", "palm", "back", "back", "in+up", "5"),
    "X": ("1", "index2", "index2", "down", "in+up", "1"),
    "Y": ("B", "index_tip", "index1", "in", "forward", None),
    "Z": ("claw", "middle_tip", "palm", "in", "forward", None),
}


def letter_sign(letter: str) -> Sign:
    """The fingerspelling gloss of one letter (kind 'letter', ~0.5 s)."""
    shape, contact, point, palm, fingers, base_shape = LETTERS[letter]
    move = Move("shake", "up", 0.03, 1) if letter in ("J", "H") else _TAP
    base = SPELL_BASE if base_shape is None else Hand(
        base_shape, SPELL_BASE.loc, SPELL_BASE.palm, SPELL_BASE.fingers,
        offset=SPELL_BASE.offset)
    dom = Hand(shape, f"nondom:{point}", palm, fingers, contact=contact, move=move)
    return Sign(letter, (letter.lower(),), dom, nondom=base, duration=0.5, kind="letter")
