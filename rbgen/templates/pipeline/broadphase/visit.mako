<%doc>
  Code shared by the count and write kernels of the broadphases (imported as
  a namespace; emits nothing by itself). A visit runs twice: mode "count"
  counts the pairs a work-item owns, mode "write" stores them from its scanned
  offset `next` (see store_pair in common.cl.mako).
</%doc>

<%def name="emit(mode, first, second)">\
% if mode == "count":
++found;\
% else:
store_pair(pairs_a, pairs_b, capacity, next++, ${first}, ${second});\
% endif
</%def>

<%def name="start(mode, owner='slot')">\
% if mode == "count":
uint found = 0;\
% else:
uint next = pair_offsets[${owner}];\
% endif
</%def>

<%doc>
  Large bodies stay out of the grid and the sweep: every small body tests
  each large one and a large body tests the large ones of higher index, so
  each pair involving a large body is met exactly once. The large bodies are
  entries [first, last) of a list; `fetch` declares `other` (body index) and
  `other_box` (Aabb) for entry k; `accept` may narrow the partners (owner
  emission keeps those of higher index). In scope: static_flags and the
  visiting body's self_index, lower, upper and small.
</%doc>
<%def name="visit_large_bodies(mode, first, last, fetch, accept='(small || other > self_index) && other != self_index')">\
    for (uint k = ${first}; k < ${last}; ++k) {
        ${fetch}
        if (${accept}
            && pair_allowed(static_flags, self_index, other)
            && boxes_overlap(lower, upper, other_box.lower.xyz, other_box.upper.xyz))
            ${emit(mode, "self_index", "other")}
    }
</%def>

<%def name="count_arguments()">\
        __global uint* pair_counts\
</%def>

<%def name="write_arguments()">\
        __global const uint* pair_offsets,
        __global const uint* pairs_found,
        const uint capacity,
        __global uint* pairs_a,
        __global uint* pairs_b,
        __global BroadphaseStatus* status\
</%def>

<%def name="publish_totals()">\
    /* Work-item 0 publishes the totals: every pair found is counted, at most
     * `capacity` are stored (the host grows the buffer and redoes the query). */
    if (get_global_id(0) == 0) {
        status->pairs_found = pairs_found[0];
        status->pair_count = min(pairs_found[0], capacity);
    }
</%def>
