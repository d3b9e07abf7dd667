// MathJax configuration for pymdownx.arithmatex (generic mode): typesets the \( \) and \[ \]
// spans of the appendix pages. MathJax itself is loaded by the reader's browser (mkdocs.yml,
// extra_javascript); the site builds without it, and without it the equations show as TeX.
window.MathJax = {
  tex: {
    inlineMath: [["\\(", "\\)"]],
    displayMath: [["\\[", "\\]"]],
    processEscapes: true,
    processEnvironments: true
  },
  options: {
    ignoreHtmlClass: ".*|",
    processHtmlClass: "arithmatex"
  }
};

document$.subscribe(() => {
  if (window.MathJax && MathJax.typesetPromise) {
    MathJax.startup.output.clearCache();
    MathJax.typesetClear();
    MathJax.texReset();
    MathJax.typesetPromise();
  }
});
