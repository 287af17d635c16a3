"""The point engine's tuning constants, in one place.

Each constant says what it is, what it trades (what a larger or smaller value would cost or
risk), the value that turns its rule off (``Off:``), and the tests that pin it
(``module::test`` of ``tests/worker/``): tests that fail when the value is halved or doubled,
or where none does, when its rule is turned off. ``python audits/config_pins.py`` runs each
constant's pins with the value moved and reports the ones that hold nothing.
``tests/worker/test_engine_config.py`` checks that every constant here names its pins and that
they exist.

The engine reads these as ``cfg.NAME`` at call time, and its compiled helpers take them as
arguments, so a test or an audit can change one for a run without recompiling.

User-facing knobs (tolerances, budgets, windows) are ``SolverSettings`` fields, not here.
"""

from __future__ import annotations

from worker.solvers import measure as ms

# ------------------------------------------------------------------ batches and the clock

# |x|∞ beyond this times the natural scale is divergence: the kernel stops and the point fails.
# Trades: smaller, large but bounded responses (near an undamped resonance) fail; larger,
# a diverging run costs more periods before it is stopped.
# Off: DIVERGENCE_FACTOR = inf
# Pinned by:
#   test_engine::test_divergence_is_a_failure_for_every_method
DIVERGENCE_FACTOR = 1e6

# Target seconds per batch of periods: how often the point's limits and cancel are seen.
# Trades: larger, a cancel or wall limit is seen later; smaller, more interpreter time per
# period at slow points (batches are only cut short where periods are slow).
# Off: BATCH_S = inf
# Pinned by:
#   test_limits::test_slow_batches_are_cut_short
BATCH_S = 0.25

# Periods per batch while the trajectory approaches an orbit waiting for it (_reached): it is
# seen within this many periods of being reached.
# Trades: larger, points run longer past their proof; smaller, ~10 µs of batch overhead per
# batch.
# Off: PENDING_BATCH = 1000000000
# Pinned by:
#   test_limits::test_a_reached_pending_orbit_is_seen_within_pending_batch_periods
PENDING_BATCH = 4

# ------------------------------------------------------------------ the sample buffers

# Stroboscopic samples kept for extrapolation and the approach tests.
# Trades: larger, slower orbits (longer periods, multipliers nearer 1) are recognised, at more
# memory and work per check; smaller, periods above RECENT/2 - 1 are not watched.
# Pinned by:
#   test_engine::test_an_orbit_whose_map_its_newest_returns_follow_vetoes_the_irregular_claim
RECENT = 64

# An irregular claim waits while the p-spaced differences of the samples shrank at each of the
# last SHRINK_RETURNS returns and SHRINK_FACTOR-fold over them (_shrinking_p): the response
# converges steadily to a period-p orbit. Chaos shrinks seven in a row by chance about once in
# 5,040 tries of one p.
# Trades: fewer returns or a smaller factor, chaos is mistaken for an approach more often (the
# claim waits, the point runs to its budget); more, slow approaches are claimed irregular.
# Off: SHRINK_FACTOR = inf
# Pinned by:
#   test_engine::test_steadily_shrinking_differences_show_a_long_orbit_being_approached
#   test_engine::test_a_repeat_near_a_shorter_period_waits_until_it_is_proven
SHRINK_RETURNS = 6
SHRINK_FACTOR = 10.0
# Samples kept for _shrinking_p: every p up to the longest period recognised.
HISTORY = (SHRINK_RETURNS + 2) * ms.MAX_PERIOD

# ... and while, over all the samples kept, the p-spaced differences stay within CREEP_NEAR of
# the state and their largest in each of CREEP_BLOCKS consecutive stretches falls from one to
# the next, to at most CREEP_DROP of the oldest's (_creeping_p): a slow approach (a multiplier up
# to ~0.9992 a period) that the tests above miss while the windows' Γ drifts too smoothly for
# the trend test. A response whose differences are only modulated slowly (near a period-13
# orbit at Figure 5's θ 0.3, gap 1, γ_r 1.2) falls by 5-7 % over the stretches.
# Trades: a looser drop or a larger NEAR, modulated responses wait to their budget (unsettled);
# tighter, slow approaches are claimed irregular.
# Off: CREEP_NEAR = 0.0
# Pinned by:
#   test_engine::test_differences_that_creep_down_show_an_orbit_approached_at_a_multiplier_near_1
CREEP_NEAR = 1e-2
CREEP_BLOCKS = 8
CREEP_DROP = 0.8

# ------------------------------------------------------------------ orbit search and proof

# Extrapolate-and-confirm cycles per candidate orbit.
# Trades: more, side runs spent on sequences that are not converging; fewer, orbits found a few
# periods later by the next candidate.
# Off: MAX_CYCLES = 1
# Pinned by:
#   test_engine::test_a_slowly_contracting_orbit_is_found_not_claimed_irregular
MAX_CYCLES = 4

# A first extrapolation must fit the sequence to this relative residual, and use at most
# MAX_RRE samples (p apart).
# Trades: a looser fit, side runs spent on sequences that are not yet a linear contraction;
# more samples, older (less linear) returns in the fit.
# Pinned by:
#   test_engine::test_an_orbit_whose_neighbourhood_has_grazing_impacts_is_not_reported
#   test_engine::test_a_stable_orbit_beside_chaos_is_not_reported
#   test_engine::test_a_slowly_contracting_orbit_is_found_not_claimed_irregular
MAX_FIT = 1e-2
MAX_RRE = 8

# A Newton step on the p-period map (the event method's exact matrix) may be at most this many
# times the distance a contraction's residual allows (r / (1 − ρ)); longer ones fall back on
# extrapolation.
# Trades: larger, steps out of the linear regime are trusted (wasted confirmations); smaller,
# Newton's help is refused where the sequence's Ritz values miss a slow mode.
# Off: NEWTON_REACH = 0.0
# Pinned by:
#   test_engine::test_a_slowly_contracting_orbit_is_found_not_claimed_irregular
NEWTON_REACH = 10.0

# Relative state perturbation of the monodromy matrix's finite differences.
# Trades: larger, the differences leave the linear regime; smaller, rounding dominates them.
# Off: FD_STEP = 1.0
# Pinned by:
#   test_engine_config::test_the_finite_difference_multiplier_is_the_exact_one
FD_STEP = 1e-7

# The monodromy check of an orbit the trajectory reached by itself may cost at most this many
# times the periods the point has run: at most triple its cost.
# Trades: larger, many-mode cells reached within a few periods cost 10-15 times more; smaller,
# more reached orbits are reported without a multiplier.
# Off: CHECK_COST = 0
# Pinned by:
#   test_engine::test_an_unstable_orbit_the_samples_reach_is_not_reported
CHECK_COST = 2

# A pending orbit (its attraction not proven when confirmed) is reached once the trajectory has
# been REACH_SHRINK times closer to it than when it was confirmed at REACH_HOLD returns in a row
# (a chaotic trajectory may pass near an orbit once).
# Trades: smaller, a trajectory passing a saddle along its stable manifold is taken as reached;
# larger, points run longer before a reached orbit is reported.
# Off: REACH_SHRINK = inf
# (REACH_HOLD: no test holds its value within ×½…×2; three returns in a row is the guard
# against a single close pass that the multiplier cannot rule out.)
# Pinned by:
#   test_engine_config::test_a_slowly_attracting_pending_orbit_is_reached_within_the_budget
REACH_SHRINK = 100.0
REACH_HOLD = 3

# Samples follow an orbit's linearized map when every step matches it to this fraction of the
# deviation (_follows; what an extrapolated orbit needs to be reported at once); chained fits
# also need the approach the map predicts, to the same fraction.
# Trades: looser, a stable orbit circled by another orbit or by chaos is reported though the
# trajectory never reaches it; tighter, approaching trajectories fit less often (later reports).
# Off: LINEAR_FIT = inf
# Pinned by:
#   test_engine::test_near_a_multiplier_of_modulus_one_the_samples_must_show_the_approach
#   test_engine::test_a_nearly_defective_map_measures_the_approach_by_its_slowest_contraction
LINEAR_FIT = 0.25

# Where the map brings deviations less than this much closer over MAX_RRE returns (a
# multiplier near 1), pending orbits are also fitted over all the returns the buffer holds.
# Trades: larger, more long fits (cost); smaller, slowly approached orbits wait longer.
# Off: SLOW_SHRINK = inf
# Pinned by:
#   test_engine_config::test_a_slowly_approached_orbit_is_fitted_over_all_returns
SLOW_SHRINK = 0.5

# Eigenvector matrices of the map worse conditioned than this: the approach is measured
# without them (_approach_seen's stricter fallback).
# Trades: larger, a nearly defective matrix's eigenvectors turn deviations wrongly; smaller,
# the stricter fallback refuses more genuine approaches.
# Off: EIG_COND = inf
# Pinned by:
#   test_engine::test_a_nearly_defective_map_measures_the_approach_by_its_slowest_contraction
EIG_COND = 1e8

# Periods (times the orbit's period) without periodicity signals after an unstable orbit was
# reached by the samples: they repeat near it for a while as the trajectory leaves.
# Trades: larger, a stable orbit right after it is recognised later; smaller, the same unstable
# orbit is measured again and again.
# Off: UNSTABLE_HOLD = 0
# Pinned by:
#   test_engine_config::test_an_unstable_orbit_reached_is_not_measured_again_while_near
UNSTABLE_HOLD = 4

# A p-periodic state whose q-spaced differences (q | p) are within this many periodicity_tol may
# still be approaching a period-q orbit: it must show them steady first (_divisors_steady).
# Trades: larger, more states wait for the divisor test (later reports); smaller, a period-p
# report where the trajectory is still approaching a period-q orbit.
# Off: AMBIGUOUS = 0.0
# Pinned by:
#   test_engine::test_tight_plain_iteration_reports_a_slow_period_1_orbit_as_period_1
AMBIGUOUS = 1e3

# ------------------------------------------------------------------ the linear tail

# Periods ahead the linear tail proof may search.
# Trades: larger, each proof costs more where it fails; smaller, tails that first swing close
# to a stop are proven later.
# Off: TAIL_HORIZON = 1
# Pinned by:
#   test_engine::test_a_start_already_in_the_linear_tail_simulates_nothing
TAIL_HORIZON = 200

# ------------------------------------------------------------------ irregular statistics

# Windows measured (harmonics, θ_eff) before the earliest irregular claim.
# Trades: more, measuring (slower periods) starts earlier; fewer, θ_eff rests on fewer windows.
# Pinned by:
#   test_engine::test_an_orbit_whose_map_its_newest_returns_follow_vetoes_the_irregular_claim
MIN_WINDOWS = 8

# Stationary periods an irregular claim rests on at the fewest, or a quarter of a shorter
# budget (no claim before period 300 with the default budget and window).
# Trades: fewer, transient chaos and slow modulations are claimed on short records; more, every
# irregular point runs longer.
# Off: MIN_STATIONARY = 1
# Pinned by:
#   test_engine::test_an_orbit_whose_neighbourhood_has_grazing_impacts_is_not_reported
MIN_STATIONARY = 200

# Periods per batch of the MSER rule (MSER-5), and the batches it leaves at the fewest.
# Trades: larger batches, a coarser transient cut; fewer kept, the rule's statistic is noise.
# (MSER_BATCH: no test holds its value; 5 is the published MSER-5 rule, and MSER-1 cuts the
# same transients at all 9,180 audited points.)
# Off: MSER_BATCH = 1
# Pinned by:
#   test_engine::test_batch_means_give_the_error_of_an_autocorrelated_mean
MSER_BATCH = 5
MSER_KEEP = 10

# Batch means a standard error rests on at the fewest, when they stay correlated.
# Trades: fewer, the error bar rests on an uncertain variance; more, correlated series get no
# batches long enough to decorrelate.
# Pinned by:
#   test_engine::test_a_slow_modulation_is_not_taken_for_decorrelated_batches
#   test_engine::test_batch_means_give_the_error_of_an_autocorrelated_mean
MIN_BATCHES = 10

# The lag-1 autocorrelation of k batch means counts as insignificant below DECORRELATED/√k (its
# spread for independent means is 1/√k), those at lags up to measure.MAX_PERIOD below
# (DECORRELATED + 1)/√k: batches are doubled until they are.
# Trades: larger, correlated batch means are taken as independent (error bars too small);
# smaller, batches grow needlessly and error bars rest on fewer of them.
# Pinned by:
#   test_engine::test_batch_means_give_the_error_of_an_autocorrelated_mean
#   test_engine::test_a_slow_modulation_is_not_taken_for_decorrelated_batches
DECORRELATED = 2.0

# t-statistic of the batch means' trend above which Γ is still drifting (no claim).
# Trades: larger, slow transients are claimed irregular; smaller, stationary series wait.
# Off: MAX_TREND = inf
# Pinned by:
#   test_engine_config::test_a_drifting_record_is_not_claimed_irregular
MAX_TREND = 3.0

# A stationary series whose values repeat every q <= measure.MAX_PERIOD periods to within this
# fraction of their spread (RMS of y_k - y_{k-q} over √2 times their standard deviation; 1 for
# independent values) is an almost periodic response, whose error bar is not trusted.
# Trades: larger, irregular series are called almost periodic; smaller, almost periodic ones
# get a trusted error bar.
# Off: ALMOST_PERIODIC = 0.0
# Pinned by:
#   test_engine::test_a_slow_modulation_is_not_taken_for_decorrelated_batches
ALMOST_PERIODIC = 0.1
