"""Layer 2, `measures`: uncertainty from a policy's members, and the member-free detectors beside it.

- `definitions`: each measure as a numpy function of the members' outputs (value_std, policy_std,
  policy_js, max_prob, entropy), the definition the tests check by hand.
- `estimates`: one batched call from a policy and N states to every measure (`uncertainty`,
  `member_outputs`, `act_with_uncertainty`).
- `detectors`: kNN and Mahalanobis detectors on observations or features, which need no members.

Imports `common` and `methods` only.
"""
