"""The reference harness: a provider-neutral agent loop, the paper's context policy and one
provider adapter per API (each through its official SDK)."""
