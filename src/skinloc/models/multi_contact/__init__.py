"""Multi-contact localisation: how many fingers touch one frame, and where each one is.

The modules, each public to the others (nothing private is imported across them):

* ``contacts``: the result (``ContactSet``), the count rule (``CountRule``) and noise weights;
* ``search``: the compiled search (``SearchTables``, ``search_into``, its NNLS kernels);
* ``pairs``: its seed and pair stages, pruned without changing the answer;
* ``refit``: a two-contact fit anchored at a known finger (the live pair prior's question);
* ``rule_calibration``: the count rule calibrated on the training recording alone;
* ``landing``: a second finger in time (the image's change of shape as fingers land and lift),
  its threshold calibrated on the training touches too (``CountRule.landing_change``);
* ``footprint``: a second finger in the image's footprint (wider and fuller than one finger's
  at its place), its score's weights and levels calibrated in ``rule_calibration``
  (``CountRule.footprint_two``; measured and stored, used by no count);
* ``two_point``: the skin's two-point threshold (how far apart two fingers are read as two),
  measured at calibration by ``rule_calibration`` and stored beside the rule.

A touch of strength ``s`` counts at surface point ``p`` gives about ``s * unit(p)``, where
``unit`` is the amplitude map (``skinloc.models.response_map.AmplitudeMap``: the un-normalised
image per point, negative deltas included); ``m`` fingers give the sum of their images. For a
baseline-subtracted image ``x (k,)`` the search looks for the points ``p_1..p_m`` and the
strengths ``s >= 0`` (non-negative least squares) that explain ``x`` best, with every sensor
weighted by its noise (``xw = x / sigma``, the same for the table rows)::

    gain(p_1..p_m) = max_{s >= 0} |xw|^2 - |xw - sum_j s_j unit_w(p_j)|^2   (NNLS, m <= 3)
    R_m = |xw|^2 - max gain over m points, the residual of the best m contacts

Coarse to fine: ``n_top`` spatially distinct seeds among the coarse candidates (every 16th
surface point) by their one-contact gain; every seed paired with every coarse candidate at
least ``min_separation_mm`` away (2 x 2 NNLS from a precomputed Gram matrix); the best pair
refined on the full candidate grid, one contact at a time with the others fixed (the
candidates of the 7 coarse cells around it), twice. A third contact is searched the same way
from the refined pair. The count (``CountRule``): 0 if no sensor reaches ``z_on`` noise
levels; ``m`` contacts rather than ``m - 1`` if the relative residual reduction
``rho_m = (R_{m-1} - R_m) / (R_m + misfit * |xw|^2)`` (``misfit``: the share of a touch's
energy the model typically leaves unexplained), weighed by the weakest of the ``m`` contacts'
peak signal ``z_m`` (noise levels), ``rho_m * z_m ** z_power``, reaches ``tau_m`` and ``z_m``
reaches ``z_m_min``: a strong second contact needs less relative gain than a faint one. The
thresholds are calibrated on the training recording only
(``skinloc.models.multi_contact.rule_calibration``: cross-validation over its point logs).

In a stream (``search.SearchMemory``, one per skin's live loop) a held touch skips the full
search: while the last full search counted one contact well below the rule's threshold, a
frame refines that one-contact fit and the remembered pair locally, and answers one contact
unless the pair's score comes near the threshold, the one-contact residual grows, or its
largest residual grows (a finger landing elsewhere); every ``REFRESH_FRAMES`` frames, and at a
touch's start, the full search runs again. Only a count of one is ever answered so; anything
else is the full search's answer.

One contact is reported by the model's own single-contact answer (``Engine.localise_into``),
so ``max_contacts=1`` is today's answer; its strength is the L2 norm of the image's positive
part, counts. Each contact of several is then placed by that single-contact answer on the
image less the other contacts' fitted images (a response map's ``_peel``), so that each finger
is placed as precisely as a finger alone, and has that answer's spread as its uncertainty
(mm), like a single contact; its strength is the fitted one (the L2 norm of its modelled
image's positive part, counts). Where that place falls within the minimum separation of
another contact, the search's own place stays, with the spread of its candidates weighted by
``exp(-(R(q) - R_min) / (2 chi2_red))``, ``chi2_red = max(R_min / (k - 4m), 1)``. Figures on
the real skin: ``docs/multitouch.md``.
"""
