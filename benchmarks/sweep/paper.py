"""The paper's published numbers (Tables 1 and 2) and its three environment modes."""

MODES = ("easy", "medium", "hard")
_PAPER_ALGOS = ("spgd", "ppo", "sac", "td3")
PAPER_TABLE1 = {  # (mode, env) -> {algo: (mean, std)}: the paper's Table 1
    (mode, env): dict(zip(_PAPER_ALGOS, values))
    for (mode, env), values in {
        ("easy", "training"): (
            (0.9919, 0.0121),
            (0.8184, 0.0884),
            (0.9410, 0.0572),
            (0.9552, 0.0483),
        ),
        ("easy", "testing"): (
            (0.9909, 0.0125),
            (0.8067, 0.0661),
            (0.9403, 0.0531),
            (0.9572, 0.0501),
        ),
        ("medium", "training"): (
            (0.6155, 0.0271),
            (0.7591, 0.0728),
            (0.9145, 0.0727),
            (0.9353, 0.0451),
        ),
        ("medium", "testing"): (
            (0.6178, 0.0263),
            (0.7519, 0.0623),
            (0.9098, 0.0838),
            (0.9285, 0.0437),
        ),
        ("hard", "training"): (
            (0.5321, 0.0352),
            (0.6977, 0.0732),
            (0.8739, 0.0775),
            (0.8724, 0.0680),
        ),
        ("hard", "testing"): (
            (0.5132, 0.0348),
            (0.6526, 0.0687),
            (0.8371, 0.0804),
            (0.8488, 0.0615),
        ),
    }.items()
}
# The paper's Table 2, algo -> (sim TPS, opt TPS, convergence step, training s, inference TPS, test
# conv step, control s)
PAPER_TABLE2 = {
    "ppo": (0.0086, 0.0274, "142666 ± 25390", "5141 ± 979", 0.0057, "78 ± 10", "1.13 ± 0.21"),
    "sac": (0.0086, 0.0199, "168844 ± 24889", "4833 ± 740", 0.0046, "67 ± 10", "0.89 ± 0.18"),
    "td3": (0.0086, 0.0175, "212018 ± 28484", "5456 ± 804", 0.0036, "58 ± 7", "0.71 ± 0.12"),
}
