"""Algorithm 1 over a whole sequence in numpy: the reference the streaming HMM is tested
against (inference.fusion.HmmFusion)."""

import numpy as np

from inference.fusion_design import PAPER_TRANSITION, paper_step


def paper_viterbi(
    probabilities, transition=PAPER_TRANSITION, window: int = 5
) -> tuple[np.ndarray, np.ndarray]:
    """Algorithm 1 over a whole sequence: (smooth states (N,), p(s_t) (N, 5)).

    Ends as inference.fusion's docstring documents, so it matches HmmFusion + flush.
    """
    e = np.asarray(probabilities, dtype=float)
    t_matrix = np.asarray(transition, dtype=float)
    n = len(e)
    smooth = np.empty_like(e)
    states = np.empty(n, dtype=int)
    smooth[:window] = e[:window]
    states[:window] = np.argmax(e[:window], axis=1)
    for t in range(window, n):
        states[t - 1], smooth[t] = paper_step(smooth[t - window : t], e[t], t_matrix, window)
    if n:
        states[n - 1] = int(np.argmax(smooth[n - 1]))
    return states, smooth
