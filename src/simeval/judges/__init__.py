"""VLM/LLM judges: prompt templates, score parsing, providers (OpenAI-compatible HTTP, local transformers,
replay-from-cache), a SQLite cache of every call keyed by request hash, a cost ledger, and a concurrent runner
with a rate limiter, re-asks on unparseable replies, a budget and a dry run."""
