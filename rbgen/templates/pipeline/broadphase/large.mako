<%doc>
  Shared visit of the large-body list (imported as a namespace, emits no code
  by itself). Large bodies stay out of the grid and the sweep; every small body
  tests each large one and a large body tests the large ones of higher index,
  so each pair involving a large body is met exactly once. In scope where it
  is used: aabbs, static_flags, large_bodies, large_count, and the caller's
  self_index, lower, upper and small. The caller's body sees the pair (a, b).
</%doc>
<%def name="visit_large_bodies()">\
    uint large_total = large_count[0];
    for (uint k = 0; k < large_total; ++k) {
        uint other = large_bodies[k];
        if ((small || other > self_index) && other != self_index
            && pair_allowed(static_flags, self_index, other)
            && boxes_overlap(lower, upper, aabbs[other].lower.xyz, aabbs[other].upper.xyz)) {
            uint a = min(self_index, other), b = max(self_index, other);
${caller.body()}
        }
    }
</%def>
