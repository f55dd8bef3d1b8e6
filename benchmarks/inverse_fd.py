"""The gradient check of ``mitsnerf_drt`` in numbers: every direction of ``mitsnerf check``'s ``drt_gradient`` cases,
clean, under each planted bug, and with the free-flight estimator.

For each case the volpath references are rendered once (:func:`mitsnerf.verify.drt.prepare_drt`); then each
variant's estimates (:func:`mitsnerf.verify.drt.evaluate_drt`) are printed as a table row per direction: the
estimate of ``g . v`` with its standard error, volpath's difference quotient with its own, their z, and the
family's verdict (weighted Holm over the image's pixel and channel-mean tests and the directions).

    .venv/bin/python benchmarks/inverse_fd.py [--cases drt_gradient drt_gradient_rgb] [--quality quick]
"""

from __future__ import annotations

import argparse
import dataclasses
import math


def rows(case_name: str, quality_name: str) -> list[str]:
    from mitsnerf.verify import cases as C
    from mitsnerf.verify.drt import evaluate_drt, prepare_drt
    from mitsnerf.verify.mutations import MUTATIONS, planted

    case = next(c for c in C.DRT_CASES if c.name == case_name)
    prepared = prepare_drt(case, C.QUALITIES[quality_name])
    variants = [("clean", None, case)] + [(f"planted: {m}", MUTATIONS[m], case) for m in case.detects]
    variants.append(("free-flight estimator", None, dataclasses.replace(case, estimator="free_flight")))
    out = []
    for label, mutation, c in variants:
        with planted(mutation):
            r = evaluate_drt(dataclasses.replace(prepared, case=c))
        image = r.family.tests[0]
        out.append(f"| {case_name} | {label} | image | {image.max_abs_z:.2f} (max pixel), channel means "
                   f"{', '.join(f'{z:+.2f}' for z in image.z_means)} | | | {'pass' if r.passed else 'FAIL'} |")
        for k in r.gradient:
            g, fd = r.gradient[k], r.finite_difference[k]
            z = (g[0] - fd[0]) / math.hypot(g[1], fd[1])
            out.append(f"| | | {k} | {g[0]:.4g} +/- {g[1]:.2g} | {fd[0]:.4g} +/- {fd[1]:.2g} | {z:+.2f} | |")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=["drt_gradient", "drt_gradient_rgb"])
    parser.add_argument("--quality", default="quick")
    args = parser.parse_args()

    import mitsnerf  # noqa: F401  (libLLVM before drjit)
    from mitsnerf import env

    env.set_variant()
    print("| case | variant | direction | estimate (mean +/- s.e.) | volpath FD | z | family |")
    print("|---|---|---|---|---|---|---|")
    for name in args.cases:
        for line in rows(name, args.quality):
            print(line, flush=True)


if __name__ == "__main__":
    main()
