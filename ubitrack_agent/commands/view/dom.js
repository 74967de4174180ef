// ubitrack view: what both pages' scripts share. Text from the network is set as text.

// An HTML element holding text (as text, never as markup) and a class.
export function element(tag, text, className) {
  const node = document.createElement(tag);
  if (text !== undefined && text !== null) node.textContent = String(text);
  if (className) node.className = className;
  return node;
}
