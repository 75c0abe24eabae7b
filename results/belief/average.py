"""Weight average of CommAttn checkpoints of one lineage (stochastic weight averaging at the
end of training, issue 17's "what did not work" list). Usage, from the repository root:

    .venv/bin/python results/belief/average.py OUT.pt CHECKPOINT CHECKPOINT [...]

The averaged file keeps the last checkpoint's metadata. Evaluated with
`results/capacity/paired.py` (see results/belief/README.md).
"""

import sys

import torch

from policies.checkpoint import load_checkpoint, save_checkpoint


def main(out: str, paths: list[str]) -> None:
    cks = [load_checkpoint(p) for p in paths]
    first = {k: tuple(v.shape) for k, v in cks[0]["state_dict"].items()}
    for p, c in zip(paths[1:], cks[1:], strict=True):
        if {k: tuple(v.shape) for k, v in c["state_dict"].items()} != first:
            sys.exit(f"average.py: {p} is not the network of {paths[0]} (names or shapes differ)")
    avg = dict(cks[-1])
    avg["state_dict"] = {k: sum(torch.as_tensor(c["state_dict"][k]).float() for c in cks)
                         / len(cks) for k in cks[0]["state_dict"]}
    save_checkpoint(out, avg)


if __name__ == "__main__":
    if len(sys.argv) < 4:
        sys.exit("usage: average.py OUT.pt CHECKPOINT CHECKPOINT [...]")
    main(sys.argv[1], sys.argv[2:])
