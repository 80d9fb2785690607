"""The seed paper's published figures (section V), to print beside ours.

Niparnan, Phoka, Sudsang: six objects, 100,000 random 6-finger grasps each,
mu = tan(10 deg), C++ with maxdet + LAPACK on an Intel Core 2 Quad Q6600.
"""

# Table I: object -> (unfiltered s, filtered s, speedup)
PAPER_TABLE_I = {
    "(a)": (1174.06, 395.82, 2.97),
    "(b)": (1342.35, 262.37, 5.12),
    "(c)": (1365.37, 451.52, 3.02),
    "(d)": (466.73, 98.18, 4.75),
    "(e)": (1065.49, 278.31, 3.83),
    "(f)": (442.11, 82.98, 5.33),
}
PAPER_AVG_UNFILTERED_S = 976.02
PAPER_AVG_FILTERED_S = 261.53
PAPER_AVG_SPEEDUP = 4.17

# Table II: object -> (force-closure grasps, false positives, specificity)
PAPER_TABLE_II = {
    "(a)": (25164, 28132, 0.727),
    "(b)": (16584, 19112, 0.814),
    "(c)": (14038, 30273, 0.740),
    "(d)": (35665, 40720, 0.612),
    "(e)": (23613, 28605, 0.728),
    "(f)": (36778, 39713, 0.614),
}
PAPER_AVG_FC = 25307
PAPER_AVG_FALSE_POSITIVES = 31093
PAPER_AVG_SPECIFICITY = 0.706

# Per-query cost in the paper's text.
PAPER_FILTER_MS = 0.05
PAPER_EXACT_MS = 2.62

# Derived from the averages above (not printed in the paper): the share of grasps
# passing the filter, and the exact test's cost per passed and per rejected grasp
# implied by Table I (filtered time = filter on all + exact on the passed ones).
PAPER_GRASPS = 100_000
PAPER_PASSED_SHARE = (PAPER_AVG_FC + PAPER_AVG_FALSE_POSITIVES) / PAPER_GRASPS
_PAPER_FILTER_TOTAL_S = PAPER_FILTER_MS * 1e-3 * PAPER_GRASPS
PAPER_IMPLIED_PASSED_MS = (1e3 * (PAPER_AVG_FILTERED_S - _PAPER_FILTER_TOTAL_S)
                           / (PAPER_PASSED_SHARE * PAPER_GRASPS))
PAPER_IMPLIED_REJECTED_MS = (1e3 * (PAPER_AVG_UNFILTERED_S - PAPER_AVG_FILTERED_S
                                    + _PAPER_FILTER_TOTAL_S)
                             / ((1.0 - PAPER_PASSED_SHARE) * PAPER_GRASPS))
