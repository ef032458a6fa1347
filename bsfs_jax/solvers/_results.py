"""One vocabulary of solver outcomes for every solver of the package.

`RESULTS` extends diffrax's enumeration (which extends optimistix's), so an integration
result, a Newton result and a periodic-orbit result are items of the same enumeration and
can be promoted into each other (`RESULTS.promote(diffrax_result)`). Each item carries the
message a user reads; `RESULTS.successful` is the only good outcome.

Under `jit`/`vmap` a result is a traced `EnumerationItem`: compare it with `==`, combine
with `RESULTS.where(pred, a, b)`, and read the message on the host with `RESULTS[item]`.
"""

import diffrax as dfx
import jax
import jax.numpy as jnp
import numpy as np


class RESULTS(dfx.RESULTS):  # type: ignore[misc]
    """Outcomes of integrations, Newton solves, periodic orbits and continuation."""

    non_finite = ("the state became non-finite (NaN or inf); the response diverged: check for "
                  "unphysical parameters or a too-large force")
    step_size_failed = ("the step-size controller failed (step size underflow or a non-finite "
                        "step); loosen rtol/atol or check the parameters")
    newton_failed = ("Newton's method did not converge: give a better guess (the end of a "
                     "transient simulation or a neighbouring orbit), raise max_steps, or "
                     "check the settings")
    singular_jacobian = ("the Newton matrix is singular (a fold or branch point exactly at "
                         "the requested parameter, or a degenerate system): move the "
                         "parameter slightly or continue through the point")
    harmonics_insufficient = ("harmonic balance: the orbit's time-domain defect exceeds the "
                              "tolerance with the largest allowed harmonic count; raise "
                              "max_harmonics or use the shooting method")
    invalid_input = "the inputs are not finite or not consistent"
    chunk_lost = ("not computed: the point's chunk failed on every attempt on the cluster "
                  "(the cause is in the result's metadata, failed_chunks); rerun to compute it")


def result_message(result) -> str:
    """The message of a concrete `RESULTS` item (host side)."""
    return RESULTS[result]


def result_ok(result) -> np.ndarray:
    """Boolean array: where a (possibly batched, concrete) result is `successful`."""
    return np.asarray(result._value) == int(np.asarray(RESULTS.successful._value))


def result_codes(result) -> np.ndarray:
    """The integer codes of a (batched) result, for files (0 = successful)."""
    return np.asarray(result._value)


def result_code(result):
    """The integer code of a (batched) result as an int32 array; traceable (jit/vmap), for
    arrays that must hold codes (scatters, checkpoints)."""
    return jnp.asarray(result._value)


def result_from_codes(codes) -> RESULTS:
    """The (batched) `RESULTS` item of integer codes from `result_codes`/`result_code` or a
    file; traceable. Codes are those of this package's `RESULTS` (0 = successful)."""
    if isinstance(codes, jax.core.Tracer):
        value = jnp.asarray(codes, dtype=jnp.int32)
    else:
        value = np.asarray(codes, dtype=np.int32)
    return jax.tree_util.tree_map(lambda _: value, RESULTS.successful)


def result_text(result):
    """Like `result_message`, but "successful" (not "") for a success, and batched: a str
    for one result, an array of str for a batch (for files and summaries)."""
    codes = np.asarray(result_codes(result))
    texts = [RESULTS[result_from_codes(c)] or "successful" for c in codes.ravel()]
    return texts[0] if codes.ndim == 0 else np.array(texts, dtype=str).reshape(codes.shape)
